#version 330 core
// Label pass alone (see labels.glsl).
#include "surface.glsl"
#include "labels.glsl"

layout(location = 0) out uint out0;
layout(location = 1) out uint out1;
layout(location = 2) out uint out2;
layout(location = 3) out uint out3;

void main() {
    vec3 b = surface_bary();
    uvec4 l = fetch_labels(g_uv * b, g_face, b);
    out0 = l.x;
    out1 = l.y;
    out2 = l.z;
    out3 = l.w;
}
