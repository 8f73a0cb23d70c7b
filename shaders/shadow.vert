#version 330 core
// Depth only: shadow maps and visibility probes.
#define POSITION_ONLY 1
#include "face.glsl"

void main() {
    gl_Position = clip_position();
}
