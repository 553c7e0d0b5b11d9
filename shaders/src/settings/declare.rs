//! The [`settings!`](crate::settings!) macro: declares a struct of settings.

/// Declares a struct of settings: its fields with their defaults and
/// [`Spec`]s, then (optionally) settings structs nested in it and plain fields
/// that are not settings. Generates the struct, its `Default` and its
/// [`Settings`] implementation.
///
/// ```ignore
/// shaders::settings! {
///     /// What a struct holds.
///     #[derive(Debug, Clone, PartialEq)]
///     pub struct Example in Camera {
///         /// One line on what the setting does (its doc everywhere).
///         pub zoom: f32 = 1.0, "zoom" | "zoom-factor", number(0.1, 10.0, "a factor", "×"),
///             group Camera, affects "stage_name", ui Advanced;
///     }
///     groups { pub camera: Camera }
///     plain { pub cached: bool = false }
/// }
/// ```
///
/// Each setting: the field, its type and default; its name (and a flag when
/// the command line's differs: `_` become `-` otherwise); its [`Check`]; and
/// optionally its group (the struct's otherwise), the first cached stage it
/// `affects` and its `ui` level.
#[macro_export]
macro_rules! settings {
    (
        $(#[$meta:meta])*
        $vis:vis struct $name:ident in $sgroup:ident {
            $(
                $(#[doc = $doc:literal])*
                $fvis:vis $field:ident : $ty:ty = $default:expr ,
                $key:literal $(| $flag:literal)? , $check:ident ( $($cargs:tt)* )
                $(, group $group:ident)?
                $(, affects $stage:literal)?
                $(, ui $ui:ident)?
                ;
            )*
        }
        $(groups {
            $(
                $(#[doc = $gdoc:literal])*
                $gvis:vis $gfield:ident : $gty:ty
            ),* $(,)?
        })?
        $(plain {
            $(
                $(#[doc = $pdoc:literal])*
                $pvis:vis $pfield:ident : $pty:ty = $pdefault:expr
            ),* $(,)?
        })?
    ) => {
        $(#[$meta])*
        $vis struct $name {
            $(
                $(#[doc = $doc])*
                $fvis $field: $ty,
            )*
            $($(
                $(#[doc = $gdoc])*
                $gvis $gfield: $gty,
            )*)?
            $($(
                $(#[doc = $pdoc])*
                $pvis $pfield: $pty,
            )*)?
        }

        impl Default for $name {
            fn default() -> $name {
                $name {
                    $($field: $default,)*
                    $($($gfield: Default::default(),)*)?
                    $($($pfield: $pdefault,)*)?
                }
            }
        }

        impl $crate::settings::Settings for $name {
            fn settings() -> &'static [&'static dyn $crate::settings::Setting<$name>] {
                static ALL: ::std::sync::OnceLock<
                    Vec<&'static dyn $crate::settings::Setting<$name>>,
                > = ::std::sync::OnceLock::new();
                $crate::settings::once(&ALL, || {
                    let own: Vec<&'static dyn $crate::settings::Setting<$name>> = vec![$(
                        ::std::boxed::Box::leak(::std::boxed::Box::new(
                            $crate::settings::Field::<$name, $ty> {
                                spec: $crate::settings::Spec {
                                    name: $key,
                                    flag_given: $crate::settings_or!(None $(, Some($flag))?),
                                    group: $crate::settings_or!(
                                        $crate::settings::Group::$sgroup
                                        $(, $crate::settings::Group::$group)?
                                    ),
                                    doc: concat!($($doc, "\n",)*),
                                    check: $crate::settings::$check($($cargs)*),
                                    affects: $crate::settings_or!(None $(, Some($stage))?),
                                    ui: $crate::settings_or!(
                                        $crate::settings::Ui::Basic
                                        $(, $crate::settings::Ui::$ui)?
                                    ),
                                },
                                get: |s: &$name| &s.$field,
                                get_mut: |s: &mut $name| &mut s.$field,
                                default: || $default,
                            },
                        )),
                    )*];
                    own.into_iter()
                        $($(
                            .chain($crate::settings::nest::<$name, $gty>(
                                |s: &$name| &s.$gfield,
                                |s: &mut $name| &mut s.$gfield,
                            ))
                        )*)?
                        .collect()
                })
            }
        }
    };
}

/// The second value if given, else the first (for [`settings!`](crate::settings!)).
#[doc(hidden)]
#[macro_export]
macro_rules! settings_or {
    ($default:expr) => {
        $default
    };
    ($default:expr, $given:expr) => {
        $given
    };
}
