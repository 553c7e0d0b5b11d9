//! Who may see which dataset: [`Policy`], read from a JSON file.
//!
//! ```json
//! {
//!   "rules": [
//!     {"roles": ["radiology"], "datasets": ["ct-*", "phantom"]},
//!     {"roles": ["admin"], "datasets": ["*"]}
//!   ],
//!   "hide_denied": true,
//!   "metrics_roles": ["monitoring"],
//!   "store_roles": ["modality"],
//!   "pacs_roles": ["radiology"]
//! }
//! ```
//!
//! A principal may see a dataset when a rule names one of its roles (or
//! `*`: any authenticated principal) and a pattern (`*` and `?` wildcards)
//! matching the dataset's id. Nothing else is allowed. With `hide_denied`, a
//! denied dataset answers 404 as an unknown one does (its existence is
//! itself sensitive), else 403. `metrics_roles` may read `/metrics`
//! (default: `metrics`); `store_roles` may push studies with STOW-RS
//! (default: `store`); `pacs_roles` may search the PACS and open its
//! studies (default: `pacs`).

use std::path::Path;

use globset::{Glob, GlobSet, GlobSetBuilder};
use serde::Deserialize;

/// The role that may read `/metrics` without a policy file.
const METRICS_ROLE: &str = "metrics";
/// The role that may store studies (STOW-RS) without a policy file.
const STORE_ROLE: &str = "store";
/// The role that may search and open studies from the PACS without a
/// policy file.
const PACS_ROLE: &str = "pacs";
/// The largest policy file read, bytes, and the most rules, roles and
/// patterns it may hold.
const MAX_FILE_BYTES: u64 = 4 << 20;
const MAX_RULES: usize = 10_000;
const MAX_ITEMS: usize = 1_000;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    rules: Vec<RuleFile>,
    #[serde(default)]
    hide_denied: bool,
    #[serde(default = "default_metrics_roles")]
    metrics_roles: Vec<String>,
    #[serde(default = "default_store_roles")]
    store_roles: Vec<String>,
    #[serde(default = "default_pacs_roles")]
    pacs_roles: Vec<String>,
}

fn default_metrics_roles() -> Vec<String> {
    vec![METRICS_ROLE.to_owned()]
}

fn default_store_roles() -> Vec<String> {
    vec![STORE_ROLE.to_owned()]
}

fn default_pacs_roles() -> Vec<String> {
    vec![PACS_ROLE.to_owned()]
}

/// The roles that may search and open studies from the PACS.
pub fn pacs_roles(policy: Option<&Policy>) -> Vec<String> {
    policy.map_or_else(default_pacs_roles, |p| p.pacs_roles.clone())
}

/// The roles that may store studies (STOW-RS) without a policy file.
pub fn store_roles(policy: Option<&Policy>) -> Vec<String> {
    policy.map_or_else(default_store_roles, |p| p.store_roles.clone())
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RuleFile {
    roles: Vec<String>,
    datasets: Vec<String>,
}

/// One rule: these roles may see these datasets.
#[derive(Debug, Clone)]
struct Rule {
    roles: Vec<String>,
    datasets: GlobSet,
}

/// Who may see which dataset; see the module docs.
#[derive(Debug, Clone)]
pub struct Policy {
    rules: Vec<Rule>,
    /// Whether a denied dataset answers 404 rather than 403.
    pub hide_denied: bool,
    /// The roles that may read `/metrics`.
    pub metrics_roles: Vec<String>,
    /// The roles that may store studies (STOW-RS).
    pub store_roles: Vec<String>,
    /// The roles that may search and open studies from the PACS.
    pub pacs_roles: Vec<String>,
}

impl Policy {
    /// Reads the policy file at `path` (`--policy`).
    ///
    /// # Errors
    /// [`super::FileError`], naming the file, the rule and the field.
    pub fn load(path: &Path) -> Result<Policy, super::FileError> {
        super::load_file("--policy", path, MAX_FILE_BYTES, Policy::parse)
    }

    /// The policy of a file's `text`.
    ///
    /// # Errors
    /// Which rule and field is wrong, and what was expected.
    pub fn parse(text: &str) -> Result<Policy, String> {
        let file: File = serde_json::from_str(text).map_err(|e| {
            format!(
                "{e}: expected {{\"rules\": [{{\"roles\": […], \"datasets\": […]}}], \"hide_denied\": false, \"metrics_roles\": […], \"store_roles\": […], \"pacs_roles\": […]}}"
            )
        })?;
        if file.rules.len() > MAX_RULES {
            return Err(format!("rules: expected at most {MAX_RULES}"));
        }
        let mut rules = Vec::with_capacity(file.rules.len());
        for (i, rule) in file.rules.into_iter().enumerate() {
            if rule.roles.is_empty() || rule.roles.len() > MAX_ITEMS {
                return Err(format!(
                    "rules[{i}].roles: expected 1 to {MAX_ITEMS} roles (\"*\": any authenticated user)"
                ));
            }
            if rule.datasets.is_empty() || rule.datasets.len() > MAX_ITEMS {
                return Err(format!(
                    "rules[{i}].datasets: expected 1 to {MAX_ITEMS} dataset ids or patterns"
                ));
            }
            let mut set = GlobSetBuilder::new();
            for (j, pattern) in rule.datasets.iter().enumerate() {
                let glob = Glob::new(pattern).map_err(|e| {
                    format!("rules[{i}].datasets[{j}] {pattern:?}: {e}; expected an id, * and ? as wildcards")
                })?;
                set.add(glob);
            }
            let datasets = set
                .build()
                .map_err(|e| format!("rules[{i}].datasets: {e}"))?;
            rules.push(Rule {
                roles: rule.roles,
                datasets,
            });
        }
        Ok(Policy {
            rules,
            hide_denied: file.hide_denied,
            metrics_roles: file.metrics_roles,
            store_roles: file.store_roles,
            pacs_roles: file.pacs_roles,
        })
    }

    /// Whether a principal with `roles` may see the dataset `id`.
    pub fn allows(&self, roles: &[String], id: &str) -> bool {
        self.rules.iter().any(|rule| {
            rule.roles
                .iter()
                .any(|r| r == "*" || roles.iter().any(|have| have == r))
                && rule.datasets.is_match(id)
        })
    }
}

/// The roles that may read `/metrics` without a policy file.
pub fn metrics_roles(policy: Option<&Policy>) -> Vec<String> {
    policy.map_or_else(default_metrics_roles, |p| p.metrics_roles.clone())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn roles(names: &[&str]) -> Vec<String> {
        names.iter().map(|&n| n.to_owned()).collect()
    }

    #[test]
    fn a_rule_allows_its_roles_the_datasets_it_names() {
        let policy = Policy::parse(
            r#"{"rules": [
                {"roles": ["radiology"], "datasets": ["ct-*", "phantom"]},
                {"roles": ["*"], "datasets": ["public?"]}
            ], "hide_denied": true}"#,
        )
        .expect("valid");
        assert!(policy.hide_denied);
        assert_eq!(policy.metrics_roles, ["metrics"]);
        let radiology = roles(&["staff", "radiology"]);
        assert!(policy.allows(&radiology, "ct-head"));
        assert!(policy.allows(&radiology, "phantom"));
        assert!(!policy.allows(&radiology, "mr-knee"));
        assert!(!policy.allows(&roles(&["staff"]), "ct-head"));
        assert!(policy.allows(&roles(&[]), "public1"));
        assert!(!policy.allows(&roles(&[]), "public12"));
    }

    #[test]
    fn a_bad_policy_names_the_rule_and_field() {
        for (text, expected) in [
            (
                r#"{"rules": [{"roles": [], "datasets": ["a"]}]}"#,
                "rules[0].roles",
            ),
            (
                r#"{"rules": [{"roles": ["a"], "datasets": []}]}"#,
                "rules[0].datasets",
            ),
            (
                r#"{"rules": [{"roles": ["a"], "datasets": ["[a"]}]}"#,
                "rules[0].datasets[0]",
            ),
            (r#"{"rules": [], "hide": true}"#, "unknown field `hide`"),
            (
                r#"{"rules": [{"roles": ["a"], "dataset": ["x"]}]}"#,
                "unknown field `dataset`",
            ),
        ] {
            let error = Policy::parse(text).expect_err(text);
            assert!(error.contains(expected), "{text}: {error}");
        }
    }
}
