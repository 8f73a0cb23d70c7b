#version 330 core
// Shared vertex stage of the G-buffer, label and shading passes (see face.glsl).
// With SHADOWS (the shading pass), it also hands the fragments each corner's shadow-map
// lookup point in the main light's clip space (see shadow_lookup).
#ifndef SHADOWS
#define SHADOWS 0
#endif
#include "face.glsl"

#if SHADOWS
uniform vec3 u_shadow_light;  // position of light 0, the one that casts shadows
uniform mat4 u_light_viewproj;
uniform float u_shadow_texel;  // shadow-map texel width per unit distance from the light
flat out mat3x4 g_shadow_clip;

// Light-space clip position of the point where the shadow map is read for surface
// point p with unit normal n: pushed along the normal and towards the light by a couple
// of shadow texels at its distance, or the surface shadows itself in stripes ("acne");
// grazing light needs more, as the 4x4-texel filter reaches across the slope.
vec4 shadow_lookup(vec3 p, vec3 normal) {
    float nlen = length(normal);
    vec3 n = nlen > 0.0 ? normal / nlen : vec3(0.0);
    vec3 to_light = u_shadow_light - p;
    float dist = max(length(to_light), 1e-20);
    float texel_here = u_shadow_texel * dist;
    float cos_t = clamp(abs(dot(n, to_light / dist)), 0.1, 1.0);
    float slope = sqrt(1.0 - cos_t * cos_t) / cos_t;
    float bias = texel_here * (1.5 + 2.5 * slope);
    return u_light_viewproj * vec4(p + n * 1.5 * texel_here + to_light / dist * bias, 1.0);
}
#endif

// The face's plane in world space: unit normal and its offset n . p, both computed in
// double precision on the CPU, so that the plane is exact wherever the camera is.
in vec4 in_plane;
uniform vec3 u_eye;

void main() {
    emit_face();
    gl_Position = clip_position();
    // view-space distance along the camera axis of each corner: minus view z
    vec4 to_depth = -vec4(u_view[0][2], u_view[1][2], u_view[2][2], u_view[3][2]);
    g_depth = vec3(dot(to_depth, vec4(in_p0, 1.0)), dot(to_depth, vec4(in_p1, 1.0)),
                   dot(to_depth, vec4(in_p2, 1.0)));
    // the plane relative to the eye: n . (p - eye) from the exact offset, not from
    // corners that may lie 1e5 times farther away than the face's nearest point
    g_plane = vec4(mat3(u_view) * in_plane.xyz, in_plane.w - dot(in_plane.xyz, u_eye));
#if SHADOWS
    // per corner: clip coordinates are linear in the surface point, so the fragment
    // stage gets its own (with the bias blended across the face) from barycentrics
    g_shadow_clip = mat3x4(shadow_lookup(in_p0, in_n0), shadow_lookup(in_p1, in_n1),
                           shadow_lookup(in_p2, in_n2));
#endif
}
