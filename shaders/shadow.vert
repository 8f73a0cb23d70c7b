#version 330 core
// Depth only: shadow maps and visibility probes.
#define POSITION_ONLY 1
#include "face.glsl"
uniform mat4 u_view;
uniform mat4 u_proj;

void main() {
    gl_Position = u_proj * u_view * vec4(corner_position(), 1.0);
}
