//! [`ViewArgs`]: the `render` command line's view flags, one per setting of
//! the frame request, made from the settings schema (`shaders::settings`):
//! the flag, its help, what it takes and its default all come from the
//! setting's declaration, and values are checked by the setting itself, so
//! `render`, `/api/render` and view sessions accept and refuse the same.

use std::fmt::Write as _;

use clap::error::ErrorKind;
use clap::{Arg, ArgMatches, Args, Command, FromArgMatches};
use shaders::FrameRequest;
use shaders::settings::{Raw, Setting, SettingError, Settings};

/// The frame the view flags describe.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ViewArgs {
    /// The frame request, its settings as the flags give them.
    pub frame: FrameRequest,
}

impl FromArgMatches for ViewArgs {
    fn from_arg_matches(matches: &ArgMatches) -> Result<ViewArgs, clap::Error> {
        let mut args = ViewArgs::default();
        args.update_from_arg_matches(matches)?;
        Ok(args)
    }

    fn update_from_arg_matches(&mut self, matches: &ArgMatches) -> Result<(), clap::Error> {
        for setting in FrameRequest::settings() {
            if let Some(text) = matches.get_one::<String>(setting.spec().name) {
                // The value parser accepted it already.
                setting
                    .set(&mut self.frame, &Raw::Text(text))
                    .map_err(|e| refusal(&e))?;
            }
        }
        self.frame.validate().map_err(|e| refusal(&e))
    }
}

impl Args for ViewArgs {
    fn augment_args(command: Command) -> Command {
        shaders::settings::by_group::<FrameRequest>()
            .fold(command, |command, setting| command.arg(flag(setting)))
    }

    fn augment_args_for_update(command: Command) -> Command {
        ViewArgs::augment_args(command)
    }
}

/// The flag of `setting`.
fn flag(setting: &'static dyn Setting<FrameRequest>) -> Arg {
    let spec = setting.spec();
    let long = spec.flag().into_owned();
    let default = match setting.default_text() {
        text if text.is_empty() => String::new(),
        text => format!(" [default: {text}]"),
    };
    let mut long_help = format!(
        "{}\n\nTakes {}.{default}",
        spec.doc_line(),
        setting.expected()
    );
    for (name, doc) in setting.choices() {
        let _ = write!(long_help, "\n  {name}: {doc}");
    }
    let arg = Arg::new(spec.name)
        .value_name(long.to_uppercase().replace('-', "_"))
        .long(long)
        .help(format!("{}{default}", spec.doc_line()))
        .long_help(long_help)
        .help_heading(spec.group.title())
        .allow_hyphen_values(true)
        .value_parser(move |text: &str| -> Result<String, String> {
            let mut scratch = FrameRequest::default();
            setting
                .set(&mut scratch, &Raw::Text(text))
                .map(|()| text.to_owned())
                .map_err(|e| format!("expected {}", e.expected))
        });
    if setting.kind() == "bool" {
        // `--colour-bleeding` alone turns it on; `--colour-bleeding=false` off.
        arg.num_args(0..=1)
            .require_equals(true)
            .default_missing_value("true")
    } else {
        arg
    }
}

/// A refused combination of flags, as clap reports errors.
fn refusal(e: &SettingError) -> clap::Error {
    let flag = FrameRequest::setting(&e.setting)
        .map_or_else(|| e.setting.clone(), |s| s.spec().flag().into_owned());
    clap::Error::raw(
        ErrorKind::ValueValidation,
        format!("--{flag} {}: expected {}\n", e.value, e.expected),
    )
}
