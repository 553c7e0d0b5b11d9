//! Every Rust struct mirrored in WGSL, checked field by field against naga's
//! reflection of the shaders that declare it: the same members in the same
//! order, at the same byte offsets, of the same types, and the same size. Two
//! swapped fields of equal size fail here, where comparing sizes would not.

use glam::Mat4;
use naga::{ArraySize, Module, ScalarKind, TypeInner, VectorSize};

use crate::extinction::{ExtinctionParams, LightUniform};
use crate::global_light::LightParams;
use crate::packed_volume::PackedVolume;
use crate::raycast::RaycastParams;

/// A Rust field type's WGSL spelling.
trait Wgsl {
    fn wgsl() -> String;
}

macro_rules! wgsl {
    ($($t:ty => $name:expr),* $(,)?) => {$(
        impl Wgsl for $t {
            fn wgsl() -> String {
                $name.to_string()
            }
        }
    )*};
}

wgsl!(
    f32 => "f32",
    u32 => "u32",
    [f32; 2] => "vec2<f32>",
    [f32; 3] => "vec3<f32>",
    [u32; 3] => "vec3<u32>",
    [f32; 4] => "vec4<f32>",
    Mat4 => "mat4x4<f32>",
    PackedVolume => "PackedVolume",
    LightUniform => "ExtinctionLight",
);

impl<T: Wgsl, const N: usize> Wgsl for [[T; 4]; N]
where
    [T; 4]: Wgsl,
{
    fn wgsl() -> String {
        format!("array<{}, {N}>", <[T; 4]>::wgsl())
    }
}

impl Wgsl for [u32; 4] {
    fn wgsl() -> String {
        "vec4<u32>".into()
    }
}

impl<const N: usize> Wgsl for [LightUniform; N] {
    fn wgsl() -> String {
        format!("array<ExtinctionLight, {N}>")
    }
}

/// One member: name, byte offset, WGSL type.
type Member = (String, u32, String);

/// The WGSL type of field `get` of `S` (inferred from the accessor).
fn type_of<S, T: Wgsl>(_: fn(&S) -> &T) -> String {
    T::wgsl()
}

/// The members of a mirrored Rust struct, in declaration order.
macro_rules! mirrored {
    ($s:ty { $($field:ident),* $(,)? }) => {
        [$((
            stringify!($field).to_owned(),
            std::mem::offset_of!($s, $field) as u32,
            type_of(|s: &$s| &s.$field),
        )),*]
    };
}

/// naga's spelling of a type.
fn naga_type(module: &Module, ty: naga::Handle<naga::Type>) -> String {
    let t = &module.types[ty];
    let scalar = |s: naga::Scalar| match (s.kind, s.width) {
        (ScalarKind::Float, 4) => "f32".to_owned(),
        (ScalarKind::Uint, 4) => "u32".to_owned(),
        (ScalarKind::Sint, 4) => "i32".to_owned(),
        other => format!("{other:?}"),
    };
    let n = |v: VectorSize| v as u32;
    match &t.inner {
        TypeInner::Scalar(s) => scalar(*s),
        TypeInner::Vector { size, scalar: s } => format!("vec{}<{}>", n(*size), scalar(*s)),
        TypeInner::Matrix {
            columns,
            rows,
            scalar: s,
        } => format!("mat{}x{}<{}>", n(*columns), n(*rows), scalar(*s)),
        TypeInner::Array { base, size, .. } => match size {
            ArraySize::Constant(len) => format!("array<{}, {len}>", naga_type(module, *base)),
            other => format!("array<{}, {other:?}>", naga_type(module, *base)),
        },
        TypeInner::Struct { .. } => t.name.clone().unwrap_or_default(),
        other => format!("{other:?}"),
    }
}

/// The members and size of the struct `name` declared in `source`.
fn wgsl_struct(source: &str, name: &str) -> (Vec<Member>, u32) {
    let module = naga::front::wgsl::parse_str(source)
        .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(source)));
    let (_, ty) = module
        .types
        .iter()
        .find(|(_, t)| t.name.as_deref() == Some(name))
        .unwrap_or_else(|| panic!("no struct {name} in the shader"));
    let TypeInner::Struct { members, span } = &ty.inner else {
        panic!("{name} is not a struct");
    };
    let members = members
        .iter()
        .map(|m| {
            (
                m.name.clone().unwrap_or_default(),
                m.offset,
                naga_type(&module, m.ty),
            )
        })
        .collect();
    (members, *span)
}

/// Checks the Rust struct's `rust` members and `size` against `name` in `source`.
fn check(name: &str, source: &str, rust: &[Member], size: usize) {
    let (wgsl, span) = wgsl_struct(source, name);
    for (i, (r, w)) in rust.iter().zip(&wgsl).enumerate() {
        assert_eq!(r, w, "{name} member {i}: Rust (left) against WGSL (right)");
    }
    assert_eq!(
        rust.len(),
        wgsl.len(),
        "{name}: Rust has {} members, WGSL {}",
        rust.len(),
        wgsl.len()
    );
    assert_eq!(size as u32, span, "{name}: size");
}

#[test]
fn every_mirrored_struct_matches_its_wgsl_twin_field_by_field() {
    check(
        "PackedVolume",
        crate::wgsl::RAYCAST,
        &mirrored!(PackedVolume {
            texel,
            reference_step,
            volume_dims,
            value_scale,
            atlas_size,
            value_offset,
            block_grid,
            tf_len,
        }),
        size_of::<PackedVolume>(),
    );
    let raycast = mirrored!(RaycastParams {
        inv_view_proj,
        texture_from_model,
        gradient_from_texture,
        volume,
        light_dir,
        step,
        clip_min,
        early_termination,
        clip_max,
        gradient_threshold,
        background,
        light,
        phong,
        width,
        height,
        flags,
        mode,
        max_steps,
        light_offset,
        first_row,
        image_height,
        window,
        faint_weight,
    });
    for source in [
        crate::wgsl::RAYCAST,
        crate::wgsl::RAYCAST_LIT,
        crate::wgsl::RAYCAST_EXTINCTION,
        crate::wgsl::REFERENCE,
    ] {
        check(
            "RaycastParams",
            source,
            &raycast,
            size_of::<RaycastParams>(),
        );
    }
    let light = mirrored!(LightParams {
        model_from_texture,
        texture_from_model,
        light,
        scatter_direction,
        volume,
        svr_dims,
        intensity,
        segment,
        scatter_radius,
        step,
        blend,
        regions,
        max_steps,
        seam_level,
        seam_outward,
        _pad0,
    });
    for source in [
        crate::wgsl::LOCAL_OPACITY,
        crate::wgsl::GLOBAL_OPACITY,
        crate::wgsl::DIRECT_LIGHT,
        crate::wgsl::IN_SCATTER,
        crate::wgsl::DIRECT_LIGHT_REFERENCE,
        crate::wgsl::LIGHT_SEAMS,
    ] {
        check("LightParams", source, &light, size_of::<LightParams>());
    }
    let extinction = mirrored!(ExtinctionParams {
        grid,
        channels,
        volume,
        opacity_scale,
        ray_step,
        cone_first,
        cone_growth,
        axis,
        sub,
        ao_radius,
        ao_shells,
        ambient,
        ao_norm,
        ao_strength,
        cone_tan,
        light_count,
        _pad0,
        _pad1,
        _pad2,
        lights,
        shell_radii,
        shell_weights,
    });
    let light_uniform = mirrored!(LightUniform {
        position,
        colour,
        spot
    });
    for source in [
        crate::wgsl::EXTINCTION_SAT,
        crate::wgsl::AMBIENT_OCCLUSION,
        crate::wgsl::AMBIENT_OCCLUSION_REFERENCE,
        crate::wgsl::SOFT_SHADOW,
        crate::wgsl::SHADOW_RAY,
    ] {
        check(
            "ExtinctionParams",
            source,
            &extinction,
            size_of::<ExtinctionParams>(),
        );
        check(
            "ExtinctionLight",
            source,
            &light_uniform,
            size_of::<LightUniform>(),
        );
    }
}
