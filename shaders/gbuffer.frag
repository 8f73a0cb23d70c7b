#version 330 core
// G-buffer: face id + 1 (0 = background), perspective-correct barycentrics + view
// depth, UV. Barycentrics are clamped and renormalised: at grazing angles the rasteriser's
// snapped vertex positions can put a covered pixel centre a hair outside the triangle.
in vec3 v_bary;
in float v_depth;
in vec2 v_uv;
flat in int v_face;

layout(location = 0) out int out_face;
layout(location = 1) out vec4 out_bary_depth;
layout(location = 2) out vec2 out_uv;

void main() {
    out_face = v_face + 1;
    vec3 b = clamp(v_bary, 0.0, 1.0);
    out_bary_depth = vec4(b / (b.x + b.y + b.z), v_depth);
    out_uv = v_uv;
}
