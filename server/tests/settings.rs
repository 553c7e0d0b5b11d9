//! The settings schema, walked: for every view setting `GET /api/settings`
//! describes, values made from that description (its bounds and just beyond,
//! its choices, its default, malformed text) go through the `render` command
//! line, the `/api/render` query and a view session's patch. All three must
//! accept the same values (giving the same setting the same value) and refuse
//! the same values with the same words of what was expected, which must be
//! what `GET /api/settings` says the setting takes.
#![expect(clippy::print_stdout, reason = "tests report what they measured")]

use clap::{Args, FromArgMatches};
use serde_json::{Value as Json, json};
use server::cli::ViewArgs;
use server::protocol::{ClientMessage, parse_client_message};
use server::{Dataset, View};
use shaders::FrameRequest;
use shaders::settings::Settings;

/// One value of a setting, as text (query, command line) and as JSON (view
/// sessions), and whether the schema's description says it is valid.
#[derive(Debug)]
struct Sample {
    text: String,
    json: Json,
    valid: bool,
}

fn sample(text: impl Into<String>, json: Json, valid: bool) -> Sample {
    Sample {
        text: text.into(),
        json,
        valid,
    }
}

/// Values worth trying, from the setting's description alone.
fn samples(d: &Json) -> Vec<Sample> {
    let number = |v: f64, valid| sample(v.to_string(), json!(v), valid);
    let text = |t: &str, valid| sample(t, json!(t), valid);
    let mut out = vec![text("nonsense", false), text("", false)];
    match d["kind"].as_str().unwrap_or_default() {
        "number" | "whole" => {
            let (min, max) = (
                d["min"].as_f64().expect("min"),
                d["max"].as_f64().expect("max"),
            );
            let span = (max - min).max(1.0);
            let whole = d["kind"] == "whole";
            let mid = if whole {
                ((min + max) / 2.0).floor()
            } else {
                (min + max) / 2.0
            };
            out.extend([
                number(min, true),
                number(max, true),
                number(mid, true),
                number(min - span / 100.0 - 1.0, false),
                number(max + span / 100.0 + 1.0, false),
                text("NaN", false),
                text("inf", false),
            ]);
            if whole {
                out.push(number(min + 0.5, false));
            }
        }
        "one_of" => {
            let values: Vec<u64> = d["values"]
                .as_array()
                .expect("values")
                .iter()
                .filter_map(Json::as_u64)
                .collect();
            for &v in &values {
                out.push(number(v as f64, true));
            }
            let missing = (0..)
                .find(|v| !values.contains(v))
                .expect("a missing value");
            out.push(number(missing as f64, false));
        }
        "choice" => {
            for choice in d["choices"].as_array().expect("choices") {
                out.push(text(choice["name"].as_str().expect("name"), true));
            }
        }
        "bool" => out.extend([
            text("maybe", false),
            sample("true", json!(true), true),
            sample("false", json!(false), true),
        ]),
        "colour" => out.extend([
            text("ff8000", true),
            text("red", false),
            text("ff80001", false),
        ]),
        "text" => {
            let extra = match d["name"].as_str() {
                Some("tf") => vec![
                    text("-100:000000:0,300:ffeedd:0.5", true),
                    text("300:ffffff", false),
                ],
                Some("dataset") => vec![text("phantom", true), text("lung", false)],
                Some("clip") => vec![text("0,0.1,0,1,0.9,1", true), text("0,0,0,1,1", false)],
                Some("window") => vec![
                    text("500,2000", true),
                    text("-600,1500", true),
                    text("40,0", false),
                    text("40,-80", false),
                    text("40", false),
                    text("1e9,10", false),
                ],
                Some("light") => vec![
                    text("point:0.5,0.5,2", true),
                    text("directional:0,0,0", false),
                ],
                Some("lights") => vec![text("", true), text("spot:0,0,0:0,0,1:120", false)],
                other => panic!("no samples for the text setting {other:?}: add some"),
            };
            out.retain(|s| !(s.text.is_empty() && d["name"] == "lights"));
            out.extend(extra);
        }
        other => panic!("unknown kind {other}"),
    }
    if let Some(default) = d["default"].as_str().filter(|t| !t.is_empty()) {
        out.push(text(default, true));
    }
    out
}

fn datasets() -> Vec<Dataset> {
    vec![Dataset::phantom(16, 1 << 20).expect("phantom")]
}

/// What the query path makes of `name=text`.
fn by_query(name: &str, text: &str, datasets: &[Dataset]) -> Result<View, String> {
    View::from_query(&[(name.to_owned(), text.to_owned())], datasets).map_err(|e| e.to_string())
}

/// What a view session makes of `{"set": {name: json}}`, the message parsed
/// as the session parses it.
fn by_session(name: &str, value: &Json, datasets: &[Dataset]) -> Result<View, String> {
    let message = json!({"type": "view", "id": 1, "set": {name: value}}).to_string();
    let Ok(ClientMessage::View { set, .. }) = parse_client_message(&message) else {
        panic!("{message}: not a view message");
    };
    let mut view = View::default();
    view.patch(&set, datasets)
        .map(|()| view)
        .map_err(|e| e.to_string())
}

/// What `render --flag text` makes of it (`None`: the setting is no flag).
fn by_command_line(name: &str, text: &str) -> Option<Result<FrameRequest, String>> {
    let setting = FrameRequest::setting(name)?;
    let command = ViewArgs::augment_args(clap::Command::new("render").no_binary_name(true));
    let flag = format!("--{}", setting.spec().flag());
    // `--flag=value` keeps empty values and values that look like flags whole.
    let matches = command.try_get_matches_from([format!("{flag}={text}")]);
    Some(
        matches
            .and_then(|m| ViewArgs::from_arg_matches(&m))
            .map(|args| args.frame)
            .map_err(|e| e.to_string()),
    )
}

/// The words from "expected" to the end of the line in a refusal.
fn expected_part(message: &str) -> &str {
    let from = message.find("expected ").map_or(message, |i| &message[i..]);
    from.lines().next().unwrap_or_default().trim_end()
}

#[test]
fn every_path_accepts_and_refuses_the_same_values_with_the_same_message() {
    let datasets = datasets();
    let description = server::view::describe(&datasets);
    let settings = description["settings"].as_array().expect("settings");
    assert_eq!(
        settings.len(),
        View::settings().len(),
        "every setting is described"
    );
    let mut tried = 0;
    for d in settings {
        let name = d["name"].as_str().expect("name");
        let expected = d["expected"].as_str().expect("expected");
        for mut s in samples(d) {
            tried += 1;
            let case = format!("{name} = {:?} (JSON {})", s.text, s.json);
            // A preset the schema takes may not suit the dataset shown (the
            // phantom is CT in HU: no mr): the view refuses it, naming the
            // dataset and its presets (the command line has no dataset).
            let unsuited = name == "preset"
                && s.valid
                && !datasets[0].presets().iter().any(|p| p.name() == s.text);
            if unsuited {
                s.valid = false;
            }
            let query = by_query(name, &s.text, &datasets);
            let session = by_session(name, &s.json, &datasets);
            let command_line = by_command_line(name, &s.text).filter(|_| !unsuited);
            if unsuited {
                let (q, w) = (query.expect_err(&case), session.expect_err(&case));
                assert_eq!(expected_part(&q), expected_part(&w), "{case}");
                assert!(
                    q.contains("expected one of ct-bone, ct-soft-tissue, ct-angio, generic for dataset 'phantom'"),
                    "{case}: {q}"
                );
                continue;
            }
            match (&query, &session) {
                (Ok(q), Ok(w)) => {
                    assert!(
                        s.valid,
                        "{case}: accepted, but the description says it is not valid"
                    );
                    let setting = View::setting(name).expect("declared");
                    assert_eq!(
                        setting.json(q),
                        setting.json(w),
                        "{case}: query and session differ"
                    );
                    if let Some(c) = &command_line {
                        let c = c
                            .as_ref()
                            .unwrap_or_else(|e| panic!("{case}: the command line refused: {e}"));
                        let from_cli = FrameRequest::setting(name).expect("flag").json(c);
                        assert_eq!(
                            from_cli,
                            setting.json(q),
                            "{case}: command line and query differ"
                        );
                    }
                }
                (Err(q), Err(w)) => {
                    assert!(
                        !s.valid,
                        "{case}: refused, but the description says it is valid: {q}"
                    );
                    assert!(
                        q.starts_with(&format!("query parameter {name}=")),
                        "{case}: {q}"
                    );
                    assert!(
                        w.starts_with(&format!("view setting {name}=")),
                        "{case}: {w}"
                    );
                    assert_eq!(
                        expected_part(q),
                        expected_part(w),
                        "{case}: query and session say different things"
                    );
                    assert!(
                        expected_part(q).starts_with(&format!("expected {expected}")),
                        "{case}: '{q}' does not say what GET /api/settings says: expected {expected}"
                    );
                    if let Some(c) = &command_line {
                        let e = c
                            .as_ref()
                            .err()
                            .unwrap_or_else(|| panic!("{case}: the command line accepted it"));
                        assert!(
                            e.contains(&format!(
                                "--{}",
                                FrameRequest::setting(name).expect("flag").spec().flag()
                            )),
                            "{case}: {e}"
                        );
                        assert_eq!(
                            expected_part(e),
                            expected_part(q),
                            "{case}: command line and query say different things"
                        );
                    }
                }
                _ => panic!("{case}: query {query:?}, session {session:?}"),
            }
        }
    }
    println!(
        "{tried} values of {} settings agree on every path",
        settings.len()
    );
}

#[test]
fn every_setting_is_a_flag_and_every_default_is_what_a_fresh_view_holds() {
    let fresh = View::default();
    for setting in View::settings() {
        let spec = setting.spec();
        // The described default is the value an empty query and an empty patch give.
        let datasets = datasets();
        let from_query = View::from_query(&[], &datasets).expect("empty query");
        assert_eq!(
            setting.json(&from_query),
            setting.default_json(),
            "{}",
            spec.name
        );
        assert_eq!(
            setting.json(&fresh),
            setting.default_json(),
            "{}",
            spec.name
        );
        // The default passes its own check.
        setting
            .validate(&fresh)
            .unwrap_or_else(|e| panic!("{}: default refused: {e}", spec.name));
        // Every frame setting is a flag of render (the dataset is its argument).
        if spec.name != "dataset" {
            assert!(
                by_command_line(spec.name, &setting.default_text()).is_some(),
                "{}",
                spec.name
            );
        }
    }
}

#[test]
fn view_sessions_take_typed_values_only() {
    let datasets = datasets();
    for (name, value) in [
        ("az", json!("30")),
        ("w", json!("64")),
        ("colour_bleeding", json!("true")),
        ("shading", json!(1)),
    ] {
        let e = by_session(name, &value, &datasets).expect_err(name);
        assert!(
            e.starts_with(&format!("view setting {name}={value}: expected")),
            "{e}"
        );
    }
}

/// The README's settings tables, between these markers, are the schema's.
const TABLE_START: &str = "<!-- view settings: start (generated by `voxserve settings`; checked by server/tests/settings.rs) -->";
const TABLE_END: &str = "<!-- view settings: end -->";

#[test]
fn the_readme_lists_every_setting_as_the_schema_declares_it() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../README.md");
    let readme = std::fs::read_to_string(&path).expect("README.md");
    let tables = server::view::settings_tables();
    let generated = format!("{TABLE_START}\n{}\n{TABLE_END}", tables.trim());
    let (Some(start), Some(end)) = (readme.find(TABLE_START), readme.find(TABLE_END)) else {
        panic!("README.md lacks the markers {TABLE_START} … {TABLE_END}");
    };
    let current = &readme[start..end + TABLE_END.len()];
    if current != generated {
        // VOXSERVE_BLESS=1 writes the tables the schema gives.
        if std::env::var("VOXSERVE_BLESS").is_ok_and(|v| v == "1") {
            let updated = readme.replacen(current, &generated, 1);
            std::fs::write(&path, updated).expect("writing README.md");
            return;
        }
        panic!(
            "README.md's settings tables are not the schema's; run \
             `VOXSERVE_BLESS=1 cargo test -p voxserve-server --test settings` to rewrite them:\n{generated}"
        );
    }
}
