#version 330 core
// G-buffer: face id + 1 (0 = background), barycentrics + view depth, UV.
#include "surface.glsl"

layout(location = 0) out int out_face;
layout(location = 1) out vec4 out_bary_depth;
layout(location = 2) out vec2 out_uv;

void main() {
    vec3 b = surface_bary();
    out_face = g_face + 1;
    out_bary_depth = vec4(b, dot(g_depth, b));
    out_uv = g_uv * b;
}
