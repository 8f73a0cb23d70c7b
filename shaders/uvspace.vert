#version 330 core
// Rasterise the mesh in texture space: each corner is placed at its UV, so every texel
// learns which face covers it and where (feeds mesh.geom + gbuffer.frag). Texture row 0
// (v = 1) ends up in image row 0 after the renderer's top-down read-back.
in vec3 in_position;
in vec3 in_normal;
in vec2 in_uv;

out vec3 vs_world;
out vec3 vs_normal;
out vec2 vs_uv;
out float vs_depth;

void main() {
    gl_Position = vec4(in_uv * 2.0 - 1.0, 0.0, 1.0);
    vs_world = in_position;
    vs_normal = in_normal;
    vs_uv = in_uv;
    vs_depth = 0.0;
}
