#version 330 core
// G-buffer: face id + 1 (0 = background) and view depth, then (with BARY_UV) the
// barycentrics and UV, one target each, so that a render reads back only what it needs;
// with LABELS also the label maps of labels.glsl in one four-channel target (saves a
// draw of the mesh). Without BARY_UV the labels move up to location 2: a view that
// does not read barycentrics or UV does not write them either.
#ifndef LABELS
#define LABELS 0
#endif
#ifndef BARY_UV
#define BARY_UV 1
#endif
#include "surface.glsl"

flat in vec4 g_plane;      // see mesh.vert
uniform vec4 u_pixel_ray;  // window pixel (x, y) -> view ray (x a + b, y c + d, -1)

layout(location = 0) out int out_face;
layout(location = 1) out float out_depth;
#if BARY_UV
layout(location = 2) out vec4 out_bary;
layout(location = 3) out vec2 out_uv;
#endif
#if LABELS
#include "labels.glsl"
#if BARY_UV
layout(location = 4) out uvec4 out_labels;
#else
layout(location = 2) out uvec4 out_labels;
#endif
#endif

// View depth of the surface point the pixel shows. Inside the face: where the pixel's
// own ray meets the face's plane. Interpolating the corners' depths instead sums terms
// as large as the corners' depths, which for a face 1e5 times larger than its distance
// to the camera loses four digits to rounding. Outside (barycentrics clamped at a
// silhouette, degenerate faces): the clamped point's depth, as the barycentrics say;
// "outside" allows for the rounding of the interpolated barycentrics on an edge.
float surface_depth(vec3 b) {
    vec3 ray = vec3(gl_FragCoord.xy * u_pixel_ray.xz + u_pixel_ray.yw, -1.0);
    float on_plane = g_plane.w / dot(g_plane.xyz, ray);
    bool inside = all(greaterThanEqual(g_bary, vec3(-1e-6)));
    return inside && on_plane > 0.0 && on_plane < 3.0e38 ? on_plane : dot(g_depth, b);
}

void main() {
    vec3 b = surface_bary();
    vec2 uv = g_uv * b;
    out_face = g_face + 1;
    out_depth = surface_depth(b);
#if BARY_UV
    out_bary = vec4(b, 0.0);
    out_uv = uv;
#endif
#if LABELS
    out_labels = fetch_labels(uv, g_face, b);
#endif
}
