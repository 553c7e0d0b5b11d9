//! [`View`]: what a client asks to see, a dataset and a frame of it, read
//! from the query of `GET /api/render` ([`View::from_query`]) or merged from
//! view-session patches ([`View::patch`]), each setting checked as the
//! schema declares it (`shaders::settings`). `GET /api/settings` describes
//! these settings ([`describe`]).
//!
//! Every refusal is a [`ViewError`]; a value a setting does not take is a
//! [`SettingError`] (setting, value, what was expected) that the query
//! prefixes with "query parameter", view sessions with "view setting", so
//! both paths say the same about the same value.

use std::fmt;

use serde_json::{Map, Value as Json};
use shaders::FrameRequest;
use shaders::frame::MAX_IMAGE_EDGE;
use shaders::settings::{Raw, SettingError, Settings};

use crate::Dataset;

shaders::settings! {
    /// What a client asks to see: a dataset, and a frame of it.
    #[derive(Debug, Clone, PartialEq)]
    pub struct View in Data {
        /// The dataset to show, by id [default: the server's first]; `render`
        /// takes it as its argument (a path, or `phantom`).
        pub dataset: Option<String> = None, "dataset" | "DATASET", by_type();
    }
    groups {
        /// The frame.
        pub frame: FrameRequest,
    }
}

/// Where a value came from, for messages.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Origin {
    /// `GET /api/render`'s query.
    Query,
    /// A view session's patch.
    Session,
}

impl Origin {
    /// How messages name a setting given this way.
    pub fn noun(self) -> &'static str {
        match self {
            Origin::Query => "query parameter",
            Origin::Session => "view setting",
        }
    }
}

impl fmt::Display for Origin {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.noun())
    }
}

/// A refused view: the same words for the same value on every path, named
/// as that path names settings ([`Origin`]).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ViewError {
    /// A name no setting has.
    #[error("unknown {origin} '{name}': expected one of {}", known_names())]
    Unknown {
        /// The path it came by.
        origin: Origin,
        /// The name given (at most 64 characters of it).
        name: String,
    },
    /// A query parameter given more than once.
    #[error("{origin} '{name}' is given twice: expected it once")]
    Twice {
        /// The path it came by.
        origin: Origin,
        /// The setting.
        name: String,
    },
    /// A value the setting does not take.
    #[error("{origin} {error}")]
    Setting {
        /// The path it came by.
        origin: Origin,
        /// Which setting, the value and what was expected.
        error: SettingError,
    },
    /// A viewport too large at its device pixel ratio.
    #[error(
        "viewport {width}×{height} at device pixel ratio {dpr} is {pixels_wide}×{pixels_high} \
         pixels: expected at most {MAX_IMAGE_EDGE} per side"
    )]
    Viewport {
        /// CSS pixels.
        width: u32,
        /// CSS pixels.
        height: u32,
        /// Device pixels per CSS pixel.
        dpr: f64,
        /// Device pixels.
        pixels_wide: f64,
        /// Device pixels.
        pixels_high: f64,
    },
}

impl ViewError {
    fn unknown(origin: Origin, name: &str) -> ViewError {
        ViewError::Unknown {
            origin,
            name: name.chars().take(64).collect(),
        }
    }

    /// `error` said on `origin`'s path.
    pub fn setting(origin: Origin, error: SettingError) -> ViewError {
        ViewError::Setting { origin, error }
    }
}

/// Every setting's name, for the refusal of one nobody declared.
fn known_names() -> String {
    let known: Vec<&str> = View::settings().iter().map(|s| s.spec().name).collect();
    known.join(", ")
}

impl View {
    /// The view a query asks for: every parameter a declared setting, none
    /// given twice; checked, the dataset among `datasets`.
    ///
    /// # Errors
    /// A message naming the parameter, its value and what was expected.
    pub fn from_query(pairs: &[(String, String)], datasets: &[Dataset]) -> Result<View, ViewError> {
        let origin = Origin::Query;
        let mut view = View::default();
        for (i, (name, value)) in pairs.iter().enumerate() {
            if View::setting(name).is_none() {
                return Err(ViewError::unknown(origin, name));
            }
            if pairs[..i].iter().any(|(earlier, _)| earlier == name) {
                let name = name.clone();
                return Err(ViewError::Twice { origin, name });
            }
            view.set_named(name, &Raw::Text(value))
                .map_err(|e| ViewError::setting(origin, e))?;
        }
        view.check(datasets)
            .map_err(|e| ViewError::setting(origin, e))?;
        Ok(view)
    }

    /// This view with `set` merged in (a setting given `null` goes back to
    /// its default), checked; this view is unchanged when any is refused.
    ///
    /// # Errors
    /// A message naming the setting, its value and what was expected.
    pub fn patch(
        &mut self,
        set: &Map<String, Json>,
        datasets: &[Dataset],
    ) -> Result<(), ViewError> {
        let origin = Origin::Session;
        let mut next = self.clone();
        for (name, value) in set {
            if View::setting(name).is_none() {
                return Err(ViewError::unknown(origin, name));
            }
            let applied = match value {
                Json::Null => next.reset_named(name),
                value => next.set_named(name, &Raw::Json(value)),
            };
            applied.map_err(|e| ViewError::setting(origin, e))?;
        }
        next.check(datasets)
            .map_err(|e| ViewError::setting(origin, e))?;
        *self = next;
        Ok(())
    }

    /// Checks what no single setting can: the frame's settings together,
    /// that the dataset is one of `datasets`, and that the preset suits it.
    ///
    /// # Errors
    /// The first setting refused.
    pub fn check(&self, datasets: &[Dataset]) -> Result<(), SettingError> {
        self.frame.validate()?;
        let dataset = self.dataset(datasets)?;
        match self.frame.preset {
            Some(preset) => dataset.check_preset(preset),
            None => Ok(()),
        }
    }

    /// The dataset shown: the one named, else the first of `datasets`.
    ///
    /// # Errors
    /// When the named dataset is not among `datasets` (as [`describe`] lists them).
    pub fn dataset<'d>(&self, datasets: &'d [Dataset]) -> Result<&'d Dataset, SettingError> {
        let known = || {
            let ids: Vec<&str> = datasets.iter().map(|d| d.id.as_str()).collect();
            format!("one of {}", ids.join(", "))
        };
        match &self.dataset {
            None => datasets
                .first()
                .ok_or_else(|| SettingError::of_value("dataset", "null", known())),
            Some(id) => datasets
                .iter()
                .find(|d| d.id == *id)
                .ok_or_else(|| SettingError::of_value("dataset", format!("{id:?}"), known())),
        }
    }
}

/// Every view setting as Markdown tables, one per group, the slice views'
/// settings last, without a command-line column: view sessions alone take
/// them (`voxserve settings`, the README).
pub fn settings_tables() -> String {
    format!(
        "{}\n{}",
        shaders::settings::markdown::<View>().trim_end(),
        shaders::settings::describe::markdown_session::<shaders::slice::SliceRequest>().trim_end()
    )
}

/// `GET /api/settings`: every view setting (name, flag, group, kind, range
/// or choices, unit, default, doc, what it takes), grouped; the dataset's
/// choices are `datasets` (none listed when empty). Under `slice`, the
/// settings of a slice view (`shaders::slice::SliceRequest`), described alike.
pub fn describe(datasets: &[Dataset]) -> Json {
    let mut description = shaders::settings::describe_all::<View>();
    description["slice"] = shaders::settings::describe_all::<shaders::slice::SliceRequest>();
    let entry = description["settings"]
        .as_array_mut()
        .and_then(|all| all.iter_mut().find(|s| s["name"] == "dataset"));
    if let (Some(entry), false) = (entry, datasets.is_empty()) {
        let ids: Vec<&str> = datasets.iter().map(|d| d.id.as_str()).collect();
        entry["expected"] = Json::String(format!("one of {}", ids.join(", ")));
        entry["choices"] = datasets
            .iter()
            .map(|d| serde_json::json!({"name": d.id, "doc": d.name()}))
            .collect();
    }
    description
}

#[cfg(test)]
mod tests {
    use super::*;
    use shaders::{Camera, ClipBox, Compositing, Projection, Shading};

    fn datasets() -> Vec<Dataset> {
        vec![Dataset::phantom(16, 1 << 20).expect("phantom")]
    }

    fn query(q: &str) -> Vec<(String, String)> {
        q.split('&')
            .filter(|p| !p.is_empty())
            .map(|p| {
                let (k, v) = p.split_once('=').unwrap_or((p, ""));
                (k.to_owned(), v.to_owned())
            })
            .collect()
    }

    fn parse(q: &str) -> Result<(String, FrameRequest), String> {
        let ds = datasets();
        let view = View::from_query(&query(q), &ds).map_err(|e| e.to_string())?;
        let id = view.dataset(&ds).map_err(|e| e.to_string())?.id.clone();
        Ok((id, view.frame))
    }

    fn error(q: &str) -> String {
        parse(q).expect_err(q)
    }

    #[test]
    fn an_empty_query_gives_the_defaults() {
        let (id, r) = parse("").expect("defaults");
        assert_eq!(id, "phantom");
        assert_eq!((r.width, r.height), (512, 512));
        assert_eq!(r.camera, Camera::default());
        assert_eq!(r.shading, Shading::Gradient);
        assert_eq!((r.preset, r.tf.is_none()), (None, true));
    }

    #[test]
    fn every_parameter_is_read() {
        let q = "dataset=phantom&az=30&el=-10&dist=2.5&fov=40&roll=15&w=64&h=32\
                 &preset=ct-soft-tissue&shading=mip&step=1&proj=orthographic\
                 &clip=0,0.25,0,1,1,0.5&reduction=9&bg=%23ff8000";
        let q = q.replace("%23", "#");
        let (_, r) = parse(&q).expect("valid");
        assert_eq!(r.camera.azimuth_deg, 30.0);
        assert_eq!(r.camera.elevation_deg, -10.0);
        assert_eq!(r.camera.distance, 2.5);
        assert_eq!(r.camera.fov_y_deg, 40.0);
        assert_eq!(r.camera.roll_deg, 15.0);
        assert_eq!((r.width, r.height), (64, 32));
        assert_eq!(r.shading, Shading::Mip);
        assert_eq!(r.step_voxels, 1.0);
        assert_eq!(r.camera.projection, Projection::Orthographic);
        assert_eq!(
            r.clip,
            ClipBox {
                min: [0.0, 0.25, 0.0],
                max: [1.0, 1.0, 0.5]
            }
        );
        assert_eq!(r.reduction, 9.0);
        assert_eq!(r.background, [1.0, 128.0 / 255.0, 0.0]);
        assert_eq!(r.preset, Some(blocks::Preset::CtSoftTissue));
        let (_, r) = parse("tf=-500:000000:0,300:ff8000:0.4").expect("valid tf");
        assert_eq!(
            r.tf,
            Some(
                blocks::TransferFunction::new(vec![
                    blocks::TfPoint::new(-500.0, [0.0; 3], 0.0),
                    blocks::TfPoint::new(300.0, [1.0, 128.0 / 255.0, 0.0], 0.4),
                ])
                .expect("valid")
            )
        );
    }

    #[test]
    fn every_light_parameter_is_read() {
        let q = "shading=global&light=point:0.5,0.5,1.2&light_colour=ff8000&light_intensity=2\
                 &bias=0.3&segment=16&svr=4&scatter_radius=20&directions=42&phase_g=0.4";
        let (_, r) = parse(q).expect("valid");
        assert_eq!(r.shading, Shading::GlobalLight);
        let l = r.light;
        assert_eq!(l.source, shaders::LightSource::Point([0.5, 0.5, 1.2]));
        assert_eq!(l.colour, [1.0, 128.0 / 255.0, 0.0]);
        assert_eq!(
            (l.intensity, l.bias, l.segment_voxels, l.svr_scale),
            (2.0, 0.3, 16, 4)
        );
        assert_eq!(
            (l.scatter_radius_voxels, l.directions, l.phase_g),
            (20.0, 42, 0.4)
        );
    }

    #[test]
    fn every_extinction_parameter_is_read() {
        let q = "shading=extinction&compositing=extinction\
                 &lights=point:0.5,0.5,1.2:ff8000:2;spot:0,0,0:1,1,1:30&ambient=0.7&sat_size=64\
                 &ao_radius=6&ao_shells=2&ao_strength=1.5&colour_bleeding=true&cone_angle=10\
                 &cone_frequency=20&cone_growth=0.1&ao_method=sat&shadow_method=ray";
        let (_, r) = parse(q).expect("valid");
        assert_eq!(r.shading, Shading::Extinction);
        assert_eq!(r.compositing, Compositing::Extinction);
        let e = r.extinction;
        assert_eq!(e.lights.len(), 2);
        assert_eq!(e.lights[0].intensity, 2.0);
        assert_eq!(
            (
                e.ambient,
                e.sat_size,
                e.ao_radius,
                e.ao_shells,
                e.ao_strength
            ),
            (0.7, 64, 6, 2, 1.5)
        );
        assert!(e.colour_bleeding);
        assert_eq!(
            (e.cone_angle, e.cone_frequency, e.cone_growth),
            (10.0, 20.0, 0.1)
        );
        assert_eq!(e.shadow_method, shaders::extinction::ShadowMethod::Ray);
        let (_, r) = parse("shading=extinction&lights=").expect("no lights");
        assert!(r.extinction.lights.is_empty());
    }

    #[test]
    fn bad_values_name_the_parameter_and_the_expectation() {
        let cases = [
            (
                "w=0",
                "query parameter w=\"0\": expected a whole number of pixels from 1 to 4096",
            ),
            ("w=100000", "w=\"100000\""),
            ("h=-5", "h=\"-5\""),
            ("w=12.5", "whole number"),
            ("az=abc", "az=\"abc\": expected a number of degrees"),
            ("az=NaN", "az=\"NaN\""),
            ("el=inf", "el=\"inf\""),
            ("el=91", "from -90 to 90"),
            (
                "roll=400",
                "roll=\"400\": expected a number of degrees from -360 to 360",
            ),
            ("dist=0", "dist=\"0\""),
            ("preset=bone", "preset=\"bone\": expected one of ct-bone"),
            (
                "tf=0:ffffff",
                "tf=\"0:ffffff\": expected VALUE:RRGGBB:OPACITY",
            ),
            ("tf=0:ffffff:0.1&preset=mr", "not both"),
            ("tf=10:ffffff:0,5:000000:1", "non-decreasing"),
            (
                "shading=phong",
                "shading=\"phong\": expected one of unshaded",
            ),
            (
                "light=sun:0,0,1",
                "light=\"sun:0,0,1\": expected point:x,y,z",
            ),
            ("light=point:1,2", "expected point:x,y,z"),
            ("light=directional:0,0,0&shading=global", "zero"),
            ("svr=3", "svr=\"3\": expected 1, 2, 4 or 8"),
            (
                "segment=2",
                "segment=\"2\": expected a whole number of voxels from 4 to 32",
            ),
            ("scatter_radius=-1", "scatter_radius=\"-1\""),
            ("directions=0", "directions=\"0\""),
            ("directions=1000", "from 1 to 258"),
            ("bias=2", "bias=\"2\": expected a light level from 0 to 1"),
            ("phase_g=NaN", "phase_g=\"NaN\""),
            (
                "light_colour=white",
                "light_colour=\"white\": expected six hex digits",
            ),
            ("light_intensity=100", "light_intensity=\"100\""),
            (
                "shading=extinction&ao_shells=9",
                "ao_shells=9: expected a number of shells from 1 to 8",
            ),
            (
                "lights=lamp:0,0,0",
                "lights=\"lamp:0,0,0\": expected at most 4 lights",
            ),
            (
                "sat_size=8",
                "sat_size=\"8\": expected a whole number of cells",
            ),
            (
                "colour_bleeding=maybe",
                "colour_bleeding=\"maybe\": expected true or false",
            ),
            (
                "compositing=over",
                "compositing=\"over\": expected one of alpha or extinction",
            ),
            (
                "ao_method=rays",
                "ao_method=\"rays\": expected one of sat or sampled",
            ),
            ("cone_angle=90", "cone_angle=\"90\""),
            ("dataset=lung", "dataset=\"lung\": expected one of phantom"),
            ("zoom=2", "unknown query parameter 'zoom'"),
            ("az=1&az=2", "'az' is given twice"),
            ("step=0", "step=\"0\""),
            (
                "proj=fisheye",
                "proj=\"fisheye\": expected one of perspective or orthographic",
            ),
            (
                "clip=0,0,0,1,1",
                "clip=\"0,0,0,1,1\": expected six fractions",
            ),
            ("clip=0.5,0,0,0.4,1,1", "each min below its max"),
            ("clip=0,0,0,1,1,2", "from 0 to 1"),
            ("clip=a,0,0,1,1,1", "clip=\"a,0,0,1,1,1\""),
            (
                "reduction=0.5",
                "reduction=\"0.5\": expected a data reduction ratio from 1 to 10000",
            ),
            ("reduction=NaN", "reduction=\"NaN\""),
            ("bg=red", "bg=\"red\": expected six hex digits rrggbb"),
            ("bg=ff00zz", "bg=\"ff00zz\""),
            (
                "shading=mip&reduction=1&reduction=2",
                "'reduction' is given twice",
            ),
        ];
        for (q, want) in cases {
            let msg = error(q);
            assert!(msg.contains(want), "{q}: {msg}");
        }
    }

    #[test]
    fn a_patch_merges_typed_values_and_null_restores_the_default() {
        let ds = datasets();
        let mut view = View::default();
        let patch = |json: serde_json::Value| json.as_object().cloned().expect("object");
        view.patch(
            &patch(serde_json::json!({"az": 30, "shading": "global", "colour_bleeding": true})),
            &ds,
        )
        .expect("valid");
        assert_eq!(view.frame.camera.azimuth_deg, 30.0);
        assert_eq!(view.frame.shading, Shading::GlobalLight);
        assert!(view.frame.extinction.colour_bleeding);
        // A number given as a string, a bad one among good ones: nothing changes.
        let before = view.clone();
        for bad in [
            serde_json::json!({"el": 10, "az": "40"}),
            serde_json::json!({"el": 10, "colour_bleeding": "true"}),
            serde_json::json!({"el": 10, "zoom": 2}),
        ] {
            let e = view.patch(&patch(bad.clone()), &ds).expect_err("refused");
            assert!(
                matches!(
                    e,
                    ViewError::Setting {
                        origin: Origin::Session,
                        ..
                    } | ViewError::Unknown {
                        origin: Origin::Session,
                        ..
                    }
                ),
                "{bad}: {e}"
            );
            let text = e.to_string();
            assert!(
                text.starts_with("view setting") || text.starts_with("unknown view setting"),
                "{bad}: {text}"
            );
            assert_eq!(view, before, "{bad}");
        }
        view.patch(&patch(serde_json::json!({"az": null})), &ds)
            .expect("reset");
        assert_eq!(view.frame.camera.azimuth_deg, 0.0);
    }

    #[test]
    fn the_description_lists_every_setting_with_its_default() {
        let json = describe(&datasets());
        let settings = json["settings"].as_array().expect("settings");
        assert_eq!(settings.len(), View::settings().len());
        let az = settings.iter().find(|s| s["name"] == "az").expect("az");
        assert_eq!(az["flag"], "--azimuth");
        assert_eq!(az["min"], -3600.0);
        assert_eq!(az["default"], 0.0);
        let bias = settings.iter().find(|s| s["name"] == "bias").expect("bias");
        assert_eq!(bias["default"], 0.15);
        let shading = settings
            .iter()
            .find(|s| s["name"] == "shading")
            .expect("shading");
        assert_eq!(shading["kind"], "choice");
        assert_eq!(shading["choices"].as_array().map(Vec::len), Some(6));
    }
}
