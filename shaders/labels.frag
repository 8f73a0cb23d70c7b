#version 330 core
// Label pass: integer label textures sampled at the nearest texel, no lighting, no
// filtering, so ids (up to 65535) come back exactly.
uniform usampler2D u_labels0;
uniform usampler2D u_labels1;
uniform usampler2D u_labels2;
uniform usampler2D u_labels3;
uniform int u_count;

#include "surface.glsl"

layout(location = 0) out uint out0;
layout(location = 1) out uint out1;
layout(location = 2) out uint out2;
layout(location = 3) out uint out3;

uint fetch(usampler2D tex, vec2 uv) {
    ivec2 size = textureSize(tex, 0);
    // v = 1 is the top row of the texture image, which is uploaded as row 0.
    ivec2 texel = ivec2(floor(vec2(uv.x, 1.0 - uv.y) * vec2(size)));
    return texelFetch(tex, clamp(texel, ivec2(0), size - 1), 0).r;
}

void main() {
    vec2 uv = g_uv * surface_bary();
    out0 = fetch(u_labels0, uv);
    out1 = u_count > 1 ? fetch(u_labels1, uv) : 0u;
    out2 = u_count > 2 ? fetch(u_labels2, uv) : 0u;
    out3 = u_count > 3 ? fetch(u_labels3, uv) : 0u;
}
