//! The query string of `GET /api/render` → a [`FrameRequest`].
//!
//! | parameter | meaning | default |
//! |---|---|---|
//! | `dataset` | dataset id | the server's first dataset |
//! | `az` | camera azimuth, degrees (0 = from anterior) | 0 |
//! | `el` | camera elevation, degrees, −90..=90 | 0 |
//! | `dist` | camera distance, bounding-sphere radii, 0.05..=100 | 3 |
//! | `fov` | vertical field of view, degrees, 1..=120 | 30 |
//! | `w`, `h` | image size, pixels, 1..=4096 | 512 |
//! | `preset` | transfer-function preset | the dataset's default |
//! | `tf` | a transfer function instead of a preset: `VALUE:RRGGBB:OPACITY,…` in physical units (e.g. HU), opacity per step of the smallest spacing, at most 64 points in non-decreasing order | — |
//! | `proj` | `perspective` or `orthographic` | `perspective` |
//! | `shading` | `gradient`, `unshaded`, `mip`, `minip`, `global` (global light propagation) or `extinction` (extinction-based illumination) | `gradient` |
//! | `compositing` | `alpha` (α-blending) or `extinction` (exponential extinction, eq. 2 of Schlegel et al.) | `alpha` |
//! | `step` | sample step, voxels, 0.05..=4 | 0.5 |
//! | `clip` | clip box as six fractions of the volume's extent, `x0,y0,z0,x1,y1,z1` | `0,0,0,1,1,1` |
//! | `reduction` | data reduction (full voxels per voxel on the GPU), 1..=10000 | 1 (the device budget may force more) |
//! | `bg` | background colour, `rrggbb` hex | `000000` |
//! | `light` | `point:x,y,z` (fractions of the volume's box; inside is 0..1) or `directional:x,y,z` (towards the light, LPS) | `directional:-0.6,-0.5,0.62` |
//! | `light_colour` | `rrggbb` hex | `ffffff` |
//! | `light_intensity` | I0, 0..=16 | 1 |
//! | `bias` | minimum light level I_bias, 0..=1 | 0.15 |
//! | `segment` | local segment length L, voxels, 4..=32 | 8 |
//! | `svr` | shadow volume scale: 1, 2, 4 or 8 (one point per N³ voxels) | 2 |
//! | `scatter_radius` | in-scattering radius R_Ω, voxels, 0..=64 (0: none) | 8 |
//! | `directions` | in-scattering directions J, 1..=258 | 18 |
//! | `phase_g` | Henyey–Greenstein asymmetry, −0.9..=0.9 | 0 |
//!
//! | `lights` | extinction lights separated by `;` (at most 4): `point:x,y,z`, `directional:x,y,z` or `spot:x,y,z:dx,dy,dz:angle`, each optionally followed by `:rrggbb` and `:intensity`; empty: ambient only | `directional:-0.6,-0.5,0.62:ffffff:0.8` |
//! | `ambient` | ambient light I_A, 0..=16 | 0.5 |
//! | `sat_size` | SAT and light-cache cells along the volume's longest side, 16..=256 | 128 |
//! | `ao_radius` | ambient-occlusion radius, cells, 1..=32 | 8 |
//! | `ao_shells` | ambient-occlusion shells, 1..=16 and at most `ao_radius` | 3 |
//! | `ao_strength` | ambient-occlusion strength, 0..=16 | 0.4 |
//! | `colour_bleeding` | `true` or `false` | `false` |
//! | `cone_angle` | shadow cone half-angle, degrees, 0..=45 | 3 |
//! | `cone_frequency` | cone cuboids per volume side at the start, 1..=1000 | 50 |
//! | `cone_growth` | growth of each cone cuboid over the one before, 0..=1 | 0.05 |
//! | `ao_method` | `sat` or `sampled` (explicit sampling, the reference) | `sat` |
//! | `shadow_method` | `cone` or `ray` (one shadow ray, the reference) | `cone` |
//!
//! The light parameters apply to `shading=global`. Each request with the same
//! light refines the in-scattering by one more direction (`X-Refinement: j/J`)
//! until all J are in; a camera change keeps the light. The parameters from
//! `lights` on apply to `shading=extinction`: a transfer-function change
//! rebuilds the summed-area table, the ambient occlusion and the shadows, a
//! light change the shadows only, a camera change nothing.
//!
//! Every parameter is checked before anything renders; a bad one is refused
//! with a message that names it, the value given and what was expected. Unknown
//! and repeated parameters are refused too, so a typo never silently falls back
//! to a default.

use std::str::FromStr;

use blocks::{Preset, TransferFunction};
use shaders::extinction::{self, ExtinctionSettings};
use shaders::frame::{MAX_IMAGE_EDGE, MAX_REDUCTION, STEP_RANGE_VOXELS, parse_colour};
use shaders::light::{self, LightSettings};
use shaders::{Camera, ClipBox, Compositing, FrameRequest, Projection, Shading, camera};

use crate::Dataset;

/// The parameters `GET /api/render` accepts.
pub const PARAMETERS: [&str; 37] = [
    "dataset",
    "az",
    "el",
    "dist",
    "fov",
    "proj",
    "w",
    "h",
    "preset",
    "tf",
    "shading",
    "step",
    "clip",
    "reduction",
    "bg",
    "light",
    "light_colour",
    "light_intensity",
    "bias",
    "segment",
    "svr",
    "scatter_radius",
    "directions",
    "phase_g",
    "compositing",
    "lights",
    "ambient",
    "sat_size",
    "ao_radius",
    "ao_shells",
    "ao_strength",
    "colour_bleeding",
    "cone_angle",
    "cone_frequency",
    "cone_growth",
    "ao_method",
    "shadow_method",
];

/// The default image edge in pixels.
pub const DEFAULT_EDGE: u32 = 512;

const DEGREES: &str = "a number of degrees";
const PIXELS: &str = "a whole number of pixels";

/// The query's parameters, checked for unknown and repeated names.
struct Params<'a> {
    pairs: &'a [(String, String)],
}

impl<'a> Params<'a> {
    fn new(pairs: &'a [(String, String)]) -> Result<Params<'a>, String> {
        for (i, (name, _)) in pairs.iter().enumerate() {
            if !PARAMETERS.contains(&name.as_str()) {
                return Err(format!(
                    "unknown query parameter '{name}': expected one of {}",
                    PARAMETERS.join(", ")
                ));
            }
            if pairs[..i].iter().any(|(earlier, _)| earlier == name) {
                return Err(format!(
                    "query parameter '{name}' is given twice: expected it once"
                ));
            }
        }
        Ok(Params { pairs })
    }

    fn get(&self, name: &str) -> Option<&'a str> {
        self.pairs
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.as_str())
    }

    /// A value in `lo..=hi` (so never NaN or infinite), or `default` when absent.
    /// `what` names the kind of value in the message, e.g. "a number of degrees".
    fn ranged<T>(&self, name: &str, default: T, lo: T, hi: T, what: &str) -> Result<T, String>
    where
        T: FromStr + PartialOrd + Copy + std::fmt::Display,
    {
        let Some(text) = self.get(name) else {
            return Ok(default);
        };
        match T::from_str(text.trim()) {
            Ok(value) if (lo..=hi).contains(&value) => Ok(value),
            _ => Err(format!(
                "query parameter {name}={text:?}: expected {what} from {lo} to {hi}"
            )),
        }
    }

    /// A name parsed by `T::from_str`, or `default` when absent.
    fn named<T: FromStr>(&self, name: &str, default: T) -> Result<T, String>
    where
        T::Err: std::fmt::Display,
    {
        match self.get(name) {
            None => Ok(default),
            Some(text) => text
                .parse()
                .map_err(|e| format!("query parameter {name}: {e}")),
        }
    }
}

/// Picks the dataset and builds the frame request a query asks for.
pub fn parse<'d>(
    pairs: &[(String, String)],
    datasets: &'d [Dataset],
) -> Result<(&'d Dataset, FrameRequest), String> {
    let params = Params::new(pairs)?;
    let dataset = match params.get("dataset") {
        None => datasets.first().ok_or("the server has no datasets")?,
        Some(id) => datasets.iter().find(|d| d.id == id).ok_or_else(|| {
            let known: Vec<&str> = datasets.iter().map(|d| d.id.as_str()).collect();
            format!(
                "query parameter dataset={id:?}: expected one of {}",
                known.join(", ")
            )
        })?,
    };
    let defaults = Camera::default();
    let camera = Camera {
        azimuth_deg: params.ranged("az", defaults.azimuth_deg, -3600.0, 3600.0, DEGREES)?,
        elevation_deg: params.ranged(
            "el",
            defaults.elevation_deg,
            -camera::MAX_ELEVATION_DEG,
            camera::MAX_ELEVATION_DEG,
            DEGREES,
        )?,
        distance: params.ranged(
            "dist",
            defaults.distance,
            camera::MIN_DISTANCE,
            camera::MAX_DISTANCE,
            "a number of bounding-sphere radii",
        )?,
        fov_y_deg: params.ranged(
            "fov",
            defaults.fov_y_deg,
            camera::FOV_RANGE_DEG.0,
            camera::FOV_RANGE_DEG.1,
            DEGREES,
        )?,
        projection: params.named("proj", Projection::default())?,
    };
    let width = params.ranged("w", DEFAULT_EDGE, 1, MAX_IMAGE_EDGE, PIXELS)?;
    let height = params.ranged("h", DEFAULT_EDGE, 1, MAX_IMAGE_EDGE, PIXELS)?;
    let transfer_function = match (params.get("tf"), params.get("preset")) {
        (Some(_), Some(_)) => {
            return Err(
                "query parameters tf and preset: expected one of them, not both".to_owned(),
            );
        }
        (Some(text), None) => TransferFunction::parse(text)
            .map_err(|e| format!("query parameter tf={text:?}: {e}"))?,
        (None, _) => params
            .named::<Preset>("preset", dataset.default_preset())?
            .transfer_function(dataset.value_range()),
    };
    let shading: Shading = params.named("shading", Shading::default())?;
    let step_voxels = params.ranged(
        "step",
        0.5,
        STEP_RANGE_VOXELS.0,
        STEP_RANGE_VOXELS.1,
        "a number of voxels",
    )?;
    let reduction = params.ranged(
        "reduction",
        1.0,
        1.0,
        MAX_REDUCTION,
        "a data reduction ratio",
    )?;
    let clip: ClipBox = params.named("clip", ClipBox::default())?;
    let background = match params.get("bg") {
        None => [0.0; 3],
        Some(text) => parse_colour(text).map_err(|e| format!("query parameter bg: {e}"))?,
    };
    let defaults = LightSettings::default();
    let light = LightSettings {
        source: params.named("light", defaults.source)?,
        colour: match params.get("light_colour") {
            None => defaults.colour,
            Some(text) => {
                parse_colour(text).map_err(|e| format!("query parameter light_colour: {e}"))?
            }
        },
        intensity: params.ranged(
            "light_intensity",
            defaults.intensity,
            0.0,
            light::MAX_INTENSITY,
            "an intensity",
        )?,
        bias: params.ranged("bias", defaults.bias, 0.0, 1.0, "a light level")?,
        segment_voxels: params.ranged(
            "segment",
            defaults.segment_voxels,
            light::SEGMENT_RANGE.0,
            light::SEGMENT_RANGE.1,
            "a whole number of voxels",
        )?,
        svr_scale: match params.get("svr") {
            None => defaults.svr_scale,
            Some(text) => text
                .trim()
                .parse::<u32>()
                .ok()
                .filter(|s| light::SVR_SCALES.contains(s))
                .ok_or_else(|| format!("query parameter svr={text:?}: expected 1, 2, 4 or 8"))?,
        },
        scatter_radius_voxels: params.ranged(
            "scatter_radius",
            defaults.scatter_radius_voxels,
            0.0,
            light::MAX_SCATTER_RADIUS,
            "a number of voxels",
        )?,
        directions: params.ranged(
            "directions",
            defaults.directions,
            1,
            light::MAX_DIRECTIONS,
            "a number of directions",
        )?,
        phase_g: params.ranged(
            "phase_g",
            defaults.phase_g,
            light::PHASE_G_RANGE.0,
            light::PHASE_G_RANGE.1,
            "an asymmetry",
        )?,
    };
    let defaults = ExtinctionSettings::default();
    let extinction = ExtinctionSettings {
        sat_size: params.ranged(
            "sat_size",
            defaults.sat_size,
            extinction::SAT_SIZE_RANGE.0,
            extinction::SAT_SIZE_RANGE.1,
            "a whole number of cells",
        )?,
        ambient: params.ranged(
            "ambient",
            defaults.ambient,
            0.0,
            light::MAX_INTENSITY,
            "an intensity",
        )?,
        ao_radius: params.ranged(
            "ao_radius",
            defaults.ao_radius,
            extinction::AO_RADIUS_RANGE.0,
            extinction::AO_RADIUS_RANGE.1,
            "a whole number of cells",
        )?,
        ao_shells: params.ranged(
            "ao_shells",
            defaults.ao_shells,
            1,
            extinction::MAX_AO_SHELLS,
            "a number of shells",
        )?,
        ao_strength: params.ranged(
            "ao_strength",
            defaults.ao_strength,
            0.0,
            extinction::MAX_AO_STRENGTH,
            "a strength",
        )?,
        colour_bleeding: params.named("colour_bleeding", defaults.colour_bleeding)?,
        lights: match params.get("lights") {
            None => defaults.lights,
            Some(text) => extinction::parse_lights(text)
                .map_err(|e| format!("query parameter lights: {e}"))?,
        },
        cone_angle: params.ranged(
            "cone_angle",
            defaults.cone_angle,
            0.0,
            extinction::MAX_CONE_ANGLE,
            DEGREES,
        )?,
        cone_frequency: params.ranged(
            "cone_frequency",
            defaults.cone_frequency,
            extinction::CONE_FREQUENCY_RANGE.0,
            extinction::CONE_FREQUENCY_RANGE.1,
            "a number of cuboids per volume side",
        )?,
        cone_growth: params.ranged(
            "cone_growth",
            defaults.cone_growth,
            0.0,
            extinction::MAX_CONE_GROWTH,
            "a growth rate",
        )?,
        ao_method: params.named("ao_method", defaults.ao_method)?,
        shadow_method: params.named("shadow_method", defaults.shadow_method)?,
    };
    let compositing: Compositing = params.named("compositing", Compositing::default())?;
    let request = FrameRequest {
        camera,
        shading,
        step_voxels,
        clip,
        reduction,
        background,
        light,
        extinction,
        compositing,
        ..FrameRequest::new(width, height, transfer_function)
    };
    request.validate()?;
    Ok((dataset, request))
}

#[cfg(test)]
mod tests {
    use super::*;

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

    fn error(q: &str) -> String {
        let ds = datasets();
        parse(&query(q), &ds).expect_err(q)
    }

    #[test]
    fn an_empty_query_gives_the_defaults() {
        let ds = datasets();
        let (d, r) = parse(&[], &ds).expect("defaults");
        assert_eq!(d.id, "phantom");
        assert_eq!((r.width, r.height), (512, 512));
        assert_eq!(r.camera, Camera::default());
        assert_eq!(r.shading, Shading::Gradient);
    }

    #[test]
    fn every_parameter_is_read() {
        let ds = datasets();
        let q = "dataset=phantom&az=30&el=-10&dist=2.5&fov=40&w=64&h=32&preset=ct-soft-tissue\
                 &shading=mip&step=1&proj=orthographic&clip=0,0.25,0,1,1,0.5&reduction=9&bg=#ff8000";
        let (_, r) = parse(&query(q), &ds).expect("valid");
        assert_eq!(r.camera.azimuth_deg, 30.0);
        assert_eq!(r.camera.elevation_deg, -10.0);
        assert_eq!(r.camera.distance, 2.5);
        assert_eq!(r.camera.fov_y_deg, 40.0);
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
        let tf = Preset::CtSoftTissue.transfer_function(ds[0].value_range());
        assert_eq!(r.transfer_function, tf);
        let (_, r) = parse(&query("tf=-500:000000:0,300:ff8000:0.4"), &ds).expect("valid tf");
        assert_eq!(
            r.transfer_function,
            TransferFunction::new(vec![
                blocks::TfPoint::new(-500.0, [0.0; 3], 0.0),
                blocks::TfPoint::new(300.0, [1.0, 128.0 / 255.0, 0.0], 0.4),
            ])
            .expect("valid")
        );
    }

    #[test]
    fn every_light_parameter_is_read() {
        let ds = datasets();
        let q = "shading=global&light=point:0.5,0.5,1.2&light_colour=ff8000&light_intensity=2&bias=0.3\
                 &segment=16&svr=4&scatter_radius=20&directions=42&phase_g=0.4";
        let (_, r) = parse(&query(q), &ds).expect("valid");
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
        let ds = datasets();
        let q = "shading=extinction&compositing=extinction\
                 &lights=point:0.5,0.5,1.2:ff8000:2;spot:0,0,0:1,1,1:30&ambient=0.7&sat_size=64\
                 &ao_radius=6&ao_shells=2&ao_strength=1.5&colour_bleeding=true&cone_angle=10\
                 &cone_frequency=20&cone_growth=0.1&ao_method=sat&shadow_method=ray";
        let (_, r) = parse(&query(q), &ds).expect("valid");
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
        assert_eq!(e.shadow_method, extinction::ShadowMethod::Ray);
        let (_, r) = parse(&query("shading=extinction&lights="), &ds).expect("no lights");
        assert!(r.extinction.lights.is_empty());
    }

    #[test]
    fn bad_values_name_the_parameter_and_the_expectation() {
        let cases = [
            (
                "w=0",
                "w=\"0\": expected a whole number of pixels from 1 to 4096",
            ),
            ("w=100000", "w=\"100000\""),
            ("h=-5", "h=\"-5\""),
            ("w=12.5", "whole number"),
            ("az=abc", "az=\"abc\": expected a number of degrees"),
            ("az=NaN", "az=\"NaN\""),
            ("el=inf", "el=\"inf\""),
            ("el=91", "from -90 to 90"),
            ("dist=0", "dist=\"0\""),
            ("preset=bone", "unknown transfer-function preset 'bone'"),
            ("tf=0:ffffff", "query parameter tf=\"0:ffffff\": point 0"),
            (
                "tf=0:ffffff:0.1&preset=mr",
                "tf and preset: expected one of them",
            ),
            ("tf=10:ffffff:0,5:000000:1", "non-decreasing"),
            ("shading=phong", "unknown shading 'phong'"),
            ("light=sun:0,0,1", "light 'sun:0,0,1'"),
            (
                "light=point:1,2",
                "expected point:x,y,z or directional:x,y,z",
            ),
            (
                "light=directional:0,0,0&shading=global",
                "light direction = [0.0, 0.0, 0.0]",
            ),
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
            ("light_colour=white", "light_colour: colour 'white'"),
            ("light_intensity=100", "light_intensity=\"100\""),
            (
                "shading=extinction&ao_shells=9",
                "ambient occlusion shells = 9: expected 1 to 8",
            ),
            (
                "lights=lamp:0,0,0",
                "query parameter lights: light 'lamp:0,0,0'",
            ),
            (
                "sat_size=8",
                "sat_size=\"8\": expected a whole number of cells",
            ),
            ("colour_bleeding=maybe", "query parameter colour_bleeding"),
            ("compositing=over", "unknown compositing 'over'"),
            ("ao_method=rays", "ambient occlusion method 'rays'"),
            ("cone_angle=90", "cone_angle=\"90\""),
            ("dataset=lung", "dataset=\"lung\": expected one of phantom"),
            ("zoom=2", "unknown query parameter 'zoom'"),
            ("az=1&az=2", "'az' is given twice"),
            ("step=0", "step=\"0\""),
            ("proj=fisheye", "unknown projection 'fisheye'"),
            (
                "clip=0,0,0,1,1",
                "clip: clip box '0,0,0,1,1': expected six fractions",
            ),
            ("clip=0.5,0,0,0.4,1,1", "each min below its max"),
            ("clip=0,0,0,1,1,2", "from 0 to 1"),
            ("clip=a,0,0,1,1,1", "clip box 'a,0,0,1,1,1'"),
            (
                "reduction=0.5",
                "reduction=\"0.5\": expected a data reduction ratio from 1 to 10000",
            ),
            ("reduction=NaN", "reduction=\"NaN\""),
            ("bg=red", "bg: colour 'red': expected six hex digits rrggbb"),
            ("bg=ff00zz", "colour 'ff00zz'"),
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
}
