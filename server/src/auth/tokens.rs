//! Static API tokens for scripts: [`ApiTokens`].
//!
//! A token is `vxs_` and 64 hex digits (256 random bits); the server keeps
//! only its SHA-256, in a JSON file:
//!
//! ```json
//! {"tokens": [{"name": "nightly-export", "sha256": "9f86…", "roles": ["research"]}]}
//! ```
//!
//! `voxserve token --name NAME --role ROLE` makes one and prints the entry.

use std::collections::HashMap;
use std::path::Path;

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use super::{AuthError, FileError, Principal, Proof};

/// What every API token starts with.
pub const PREFIX: &str = "vxs_";
/// The most tokens a file may hold.
const MAX_TOKENS: usize = 10_000;
/// The most roles a token may have, and the longest name or role.
const MAX_ROLES: usize = 64;
const MAX_NAME: usize = 128;
/// The largest tokens file read, bytes.
const MAX_FILE_BYTES: u64 = 16 << 20;

/// One entry of the tokens file.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Entry {
    /// Who the token is for; the user in the audit log.
    pub name: String,
    /// The token's SHA-256, 64 lower-case hex digits.
    pub sha256: String,
    /// Its roles, as the policy file names them.
    #[serde(default)]
    pub roles: Vec<String>,
}

/// The tokens file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    tokens: Vec<Entry>,
}

/// The API tokens accepted, by hash.
#[derive(Debug, Clone)]
pub struct ApiTokens {
    by_hash: HashMap<[u8; 32], Entry>,
}

impl ApiTokens {
    /// Reads the tokens file at `path` (`--api-tokens`).
    ///
    /// # Errors
    /// [`FileError`], naming the file, the entry and the field.
    pub fn load(path: &Path) -> Result<ApiTokens, FileError> {
        super::load_file("--api-tokens", path, MAX_FILE_BYTES, |text| {
            let file: File = serde_json::from_str(text).map_err(|e| {
                format!(
                    "{e}: expected {{\"tokens\": [{{\"name\": …, \"sha256\": …, \"roles\": […]}}]}}"
                )
            })?;
            ApiTokens::new(file.tokens)
        })
    }

    /// The tokens of `entries`, checked.
    ///
    /// # Errors
    /// Which entry and field is wrong, and what was expected.
    pub fn new(entries: Vec<Entry>) -> Result<ApiTokens, String> {
        if entries.len() > MAX_TOKENS {
            return Err(format!(
                "{} tokens: expected at most {MAX_TOKENS}",
                entries.len()
            ));
        }
        let mut by_hash = HashMap::new();
        for (i, entry) in entries.into_iter().enumerate() {
            let at = format!("tokens[{i}]");
            if entry.name.is_empty() || entry.name.len() > MAX_NAME {
                return Err(format!("{at}.name: expected 1 to {MAX_NAME} characters"));
            }
            if entry.roles.len() > MAX_ROLES
                || entry
                    .roles
                    .iter()
                    .any(|r| r.is_empty() || r.len() > MAX_NAME)
            {
                return Err(format!(
                    "{at}.roles: expected at most {MAX_ROLES} roles of 1 to {MAX_NAME} characters"
                ));
            }
            let hash = parse_hash(&entry.sha256).ok_or_else(|| {
                format!("{at}.sha256: expected 64 hex digits (the token's SHA-256)")
            })?;
            if by_hash.insert(hash, entry).is_some() {
                return Err(format!("{at}.sha256: the same token is listed twice"));
            }
        }
        Ok(ApiTokens { by_hash })
    }

    /// The principal `token` stands for.
    ///
    /// # Errors
    /// [`AuthError::Refused`] for a token not in the file.
    pub fn verify(&self, token: &str) -> Result<Principal, AuthError> {
        let entry = self
            .by_hash
            .get(&hash_of(token))
            .ok_or_else(|| AuthError::Refused("unknown API token".into()))?;
        Ok(Principal {
            user: entry.name.clone(),
            proof: Proof::ApiToken,
            roles: entry.roles.clone(),
            expires: None,
        })
    }
}

/// A new random token and its entry for the tokens file.
///
/// # Errors
/// When the system has no randomness to give.
pub fn generate(name: &str, roles: Vec<String>) -> Result<(String, Entry), getrandom::Error> {
    let mut secret = [0u8; 32];
    getrandom::fill(&mut secret)?;
    let token = format!("{PREFIX}{}", hex(&secret));
    let entry = Entry {
        name: name.to_owned(),
        sha256: hex(&hash_of(&token)),
        roles,
    };
    Ok((token, entry))
}

fn hash_of(token: &str) -> [u8; 32] {
    Sha256::digest(token.as_bytes()).into()
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn parse_hash(text: &str) -> Option<[u8; 32]> {
    if text.len() != 64 || !text.is_ascii() {
        return None;
    }
    let mut hash = [0u8; 32];
    for (i, byte) in hash.iter_mut().enumerate() {
        *byte = u8::from_str_radix(&text[2 * i..2 * i + 2], 16).ok()?;
    }
    Some(hash)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_generated_token_verifies_and_others_do_not() {
        let (token, entry) = generate("export", vec!["research".into()]).expect("random");
        assert!(token.starts_with(PREFIX) && token.len() == PREFIX.len() + 64);
        assert!(!entry.sha256.contains(&token[PREFIX.len()..]));
        let tokens = ApiTokens::new(vec![entry]).expect("valid");
        let principal = tokens.verify(&token).expect("known");
        assert_eq!(principal.user, "export");
        assert_eq!(principal.roles, ["research"]);
        let mut other = token.clone();
        other.pop();
        other.push(if token.ends_with('0') { '1' } else { '0' });
        assert!(matches!(tokens.verify(&other), Err(AuthError::Refused(_))));
    }

    #[test]
    fn a_bad_entry_is_named_with_its_field() {
        let entry = |name: &str, sha: &str| Entry {
            name: name.into(),
            sha256: sha.into(),
            roles: vec![],
        };
        let good = "0".repeat(64);
        for (entries, expected) in [
            (vec![entry("", &good)], "tokens[0].name"),
            (vec![entry("a", "xyz")], "tokens[0].sha256"),
            (
                vec![entry("a", &good), entry("b", &good)],
                "tokens[1].sha256",
            ),
            (vec![entry("a", &"é".repeat(32))], "tokens[0].sha256"),
        ] {
            let error = ApiTokens::new(entries).expect_err(expected);
            assert!(error.starts_with(expected), "{error}");
        }
    }
}
