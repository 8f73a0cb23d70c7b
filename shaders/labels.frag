#version 330 core
// Label pass alone (see labels.glsl): up to four label maps in one four-channel target.
#include "surface.glsl"
#include "labels.glsl"

out uvec4 out_labels;

void main() {
    vec3 b = surface_bary();
    out_labels = fetch_labels(g_uv * b, g_face, b);
}
