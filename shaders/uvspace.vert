#version 330 core
// Rasterise the mesh in texture space: each corner is placed at its UV, so every texel
// learns which face covers it and where (with gbuffer.frag). Texture row 0 (v = 1) ends
// up in image row 0 after the renderer's top-down read-back.
#include "face.glsl"

void main() {
    gl_Position = vec4(emit_face() * 2.0 - 1.0, 0.0, 1.0);
    g_depth = vec3(0.0);
    g_plane = vec4(0.0);
}
