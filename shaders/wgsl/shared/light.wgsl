// light: the ray from a point towards the light, shared by the light stages.
// CPU twin: shaders/src/cpu/global_light.rs.

// Remaining transparency below which a light ray stops: what lies beyond can
// change the light by less than 1/1000 of I0 (a quarter of an 8-bit step).
const OPAQUE: f32 = 1e-3;

// A ray from tc0 towards the light: its texture-space direction per mm, and
// how far it may go (mm): to the light, or out of the volume's box.
struct LightRay {
    dir: vec3<f32>,
    length: f32,
}

// The ray from tc0 along the model-space unit vector `towards`, up to `limit` mm.
fn ray_along(tc0: vec3<f32>, towards: vec3<f32>, limit: f32) -> LightRay {
    var ray: LightRay;
    ray.dir = (params.texture_from_model * vec4<f32>(towards, 0.0)).xyz;
    let exit = intersect_box(tc0, ray.dir, vec3<f32>(0.0), vec3<f32>(1.0)).y;
    ray.length = max(min(exit, limit), 0.0);
    return ray;
}

// The unit vector from tc0 towards the light, and the distance to it (mm; very
// large for a directional light).
fn towards_light(tc0: vec3<f32>) -> vec4<f32> {
    if params.light.w == 0.0 {
        return vec4<f32>(params.light.xyz, 1e30);
    }
    let here = (params.model_from_texture * vec4<f32>(tc0, 1.0)).xyz;
    let d = params.light.xyz - here;
    let distance = length(d);
    if distance < 1e-6 {
        // At the light itself: nothing lies between.
        return vec4<f32>(0.0, 0.0, 1.0, 0.0);
    }
    return vec4<f32>(d / distance, distance);
}

// The ray from tc0 to the light (or out of the volume, whichever is nearer).
fn light_ray(tc0: vec3<f32>) -> LightRay {
    let to = towards_light(tc0);
    return ray_along(tc0, to.xyz, to.w);
}
