#version 330 core
// G-buffer: face id + 1 (0 = background), view depth, barycentrics, UV, one target each
// so that a render reads back only what it needs; with LABELS also the label textures
// of labels.glsl in targets 4-7 (saves a draw of the mesh).
#ifndef LABELS
#define LABELS 0
#endif
#include "surface.glsl"

layout(location = 0) out int out_face;
layout(location = 1) out float out_depth;
layout(location = 2) out vec4 out_bary;
layout(location = 3) out vec2 out_uv;
#if LABELS
#include "labels.glsl"
layout(location = 4) out uint out_label0;
layout(location = 5) out uint out_label1;
layout(location = 6) out uint out_label2;
layout(location = 7) out uint out_label3;
#endif

void main() {
    vec3 b = surface_bary();
    out_face = g_face + 1;
    out_depth = dot(g_depth, b);
    out_bary = vec4(b, 0.0);
    out_uv = g_uv * b;
#if LABELS
    uvec4 l = fetch_labels(out_uv, g_face, b);
    out_label0 = l.x;
    out_label1 = l.y;
    out_label2 = l.z;
    out_label3 = l.w;
#endif
}
