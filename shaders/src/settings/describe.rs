//! How settings are described to clients (`GET /api/settings`) and in the
//! README (Markdown tables).

use super::{Check, Group, Json, Setting, Settings};

/// A setting as `GET /api/settings` describes it.
pub fn describe<S>(setting: &dyn Setting<S>) -> Json {
    let spec = setting.spec();
    let mut entry = serde_json::json!({
        "name": spec.name,
        "flag": spec.command_line(),
        "group": spec.group.name(),
        "kind": setting.kind(),
        "doc": spec.doc_line(),
        "default": setting.default_json(),
        "expected": setting.expected(),
        "unit": spec.check.unit(),
        "ui": spec.ui.name(),
        "affects": spec.affects,
    });
    match spec.check {
        Check::Number { min, max, .. } => {
            entry["min"] = serde_json::json!(min);
            entry["max"] = serde_json::json!(max);
        }
        Check::Whole { min, max, .. } => {
            entry["min"] = serde_json::json!(min);
            entry["max"] = serde_json::json!(max);
        }
        Check::OneOf { values, .. } => entry["values"] = serde_json::json!(values),
        Check::Type => {}
    }
    let choices = setting.choices();
    if !choices.is_empty() {
        entry["choices"] = choices
            .iter()
            .map(|(name, doc)| serde_json::json!({"name": name, "doc": doc}))
            .collect();
    }
    entry
}

/// Every setting of `S` described, with the groups in order.
pub fn describe_all<S: Settings>() -> Json {
    let groups: Vec<Json> = Group::ALL
        .iter()
        .map(|g| serde_json::json!({"name": g.name(), "title": g.title()}))
        .collect();
    let settings: Vec<Json> = by_group::<S>().map(|s| describe(s)).collect();
    serde_json::json!({"groups": groups, "settings": settings})
}

/// The settings of `S`, group by group (declaration order within a group).
pub fn by_group<S: Settings>() -> impl Iterator<Item = &'static dyn Setting<S>> {
    let mut all = S::settings().to_vec();
    all.sort_by_key(|s| s.spec().group);
    all.into_iter()
}

/// The settings of `S` as a Markdown table per group, for the README.
pub fn markdown<S: Settings>() -> String {
    tables::<S>(true)
}

/// [`markdown`] without the command-line column: settings that only view
/// sessions take (the slice views').
pub fn markdown_session<S: Settings>() -> String {
    tables::<S>(false)
}

fn tables<S: Settings>(flags: bool) -> String {
    let mut out = String::new();
    for group in Group::ALL {
        let rows: Vec<String> = by_group::<S>()
            .filter(|s| s.spec().group == group)
            .map(|s| {
                let spec = s.spec();
                let default = match s.default_text() {
                    t if t.is_empty() => "—".to_owned(),
                    t => format!("`{t}`"),
                };
                let flag = if flags {
                    format!(" `{}` |", spec.command_line())
                } else {
                    String::new()
                };
                format!(
                    "| `{}` |{flag} {} | {} | {default} |",
                    spec.name,
                    spec.doc_line().replace('|', "\\|"),
                    s.expected().replace('|', "\\|"),
                )
            })
            .collect();
        if rows.is_empty() {
            continue;
        }
        let header = if flags {
            "| setting | command line | meaning | takes | default |\n|---|---|---|---|---|"
        } else {
            "| setting | meaning | takes | default |\n|---|---|---|---|"
        };
        out.push_str(&format!("\n**{}**\n\n{header}\n", group.title()));
        for row in rows {
            out.push_str(&row);
            out.push('\n');
        }
    }
    out
}
