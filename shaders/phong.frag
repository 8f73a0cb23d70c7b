#version 330 core
// Textured Phong shading with point lights, in the same form as glsynth.diff.shade:
//   colour = texel * sum(ambient + diffuse * max((n.l + wrap) / (1 + wrap), 0))
//            + sum(specular * ks * max(r.v, 0)^shininess)
// where the specular term is zero when the light is behind the surface (n.l <= 0) and
// wrap (material wrap lighting, 0 = Lambert) lets diffuse light reach past the terminator.
// Colours are display-referred: lighting acts on the sRGB-encoded texture values
// directly, as in the DermSynth3D paper's PyTorch3D renderer. Alpha is coverage.
// With SHADOWS, the diffuse and specular terms of light 0 (the main light) are scaled
// by its visibility from a shadow map (4x4-texel percentage-closer filter: soft edges);
// the torch path has no shadows, and blending never turns them on.
//
// The renderer compiles one program per light count and shadow setting (NUM_LIGHTS,
// SHADOWS are prepended as #defines): llvmpipe runs a loop with a uniform trip count
// over uniform arrays 2.4x slower than a fixed one, and evaluates a branch it cannot
// prove uniform on every pixel.
#ifndef NUM_LIGHTS
#define NUM_LIGHTS 1
#endif
#ifndef SHADOWS
#define SHADOWS 0
#endif
#ifndef DECALS
#define DECALS 0
#endif
uniform sampler2D u_texture;
uniform vec3 u_eye;
uniform vec3 u_light_pos[NUM_LIGHTS];
uniform vec3 u_light_ambient[NUM_LIGHTS];
uniform vec3 u_light_diffuse[NUM_LIGHTS];
uniform vec3 u_light_specular[NUM_LIGHTS];
uniform float u_light_falloff[NUM_LIGHTS];   // PointLight.falloff_distance (0: none)
uniform vec4 u_light_beam[NUM_LIGHTS];       // PointLight.beam: axis, exponent (0: none)
uniform float u_light_ground[NUM_LIGHTS];    // PointLight.ambient_ground (1: even)
uniform vec3 u_mat_specular;
uniform float u_shininess;
uniform float u_wrap;   // Material.wrap (0: Lambert)
#include "surface.glsl"
#include "light.glsl"

out vec4 out_color;

#if SHADOWS
#include "shadow.glsl"
#endif
#if DECALS
uniform float u_pixel_angle;   // footprint of a pixel per unit of depth
#include "decal.glsl"
#endif

void main() {
    vec3 b = surface_bary();
    vec2 uv = g_uv * b;
    vec3 world = g_world * b;
    vec3 normal = g_normal * b;
    vec3 texel = texture(u_texture, vec2(uv.x, 1.0 - uv.y)).rgb;
    float nlen = length(normal);
    vec3 n = nlen > 0.0 ? normal / nlen : vec3(0.0);
    vec3 to_eye = u_eye - world;
    vec3 view_dir = to_eye / max(length(to_eye), 1e-20);
#if DECALS
    vec4 daux;
    vec3 dax, day;
    float footprint = dot(g_depth, b) * u_pixel_angle / max(abs(dot(n, view_dir)), 0.2);
    vec4 dcol = decal_colour(uv, world, footprint, daux, dax, day);
    texel = mix(texel, dcol.rgb, dcol.a);
#endif
    vec3 light_sum = vec3(0.0);
    vec3 spec_sum = vec3(0.0);
    for (int i = 0; i < NUM_LIGHTS; ++i) {
        vec3 to_light = u_light_pos[i] - world;
        vec3 l = to_light / max(length(to_light), 1e-20);
        float cos_nl = dot(n, l);
#if SHADOWS
        float vis = i == 0 ? main_light_visibility(b) : 1.0;
#else
        float vis = 1.0;
#endif
        vis *= direct_gain(to_light, u_light_falloff[i], u_light_beam[i]);
        light_sum += u_light_ambient[i] * ambient_gain(n.y, u_light_ground[i])
                   + vis * u_light_diffuse[i] * max((cos_nl + u_wrap) / (1.0 + u_wrap), 0.0);
        if (cos_nl > 0.0) {
            vec3 r = 2.0 * cos_nl * n - l;
            float rv = max(dot(r, view_dir), 0.0);
            spec_sum += vis * u_light_specular[i] * u_mat_specular * pow(rv, u_shininess);
        }
    }
    out_color = vec4(clamp(texel * light_sum + spec_sum, 0.0, 1.0), 1.0);
}
