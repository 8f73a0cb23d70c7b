#version 330 core
// Hands every fragment its triangle's three corners (flat) plus perspective-correct
// barycentrics, so fragment shaders interpolate with clamped barycentrics exactly as
// glsynth.diff does from the G-buffer (see surface.glsl).
layout(triangles) in;
layout(triangle_strip, max_vertices = 3) out;

in vec3 vs_world[];
in vec3 vs_normal[];
in vec2 vs_uv[];
in float vs_depth[];

out vec3 g_bary;
flat out mat3 g_world;
flat out mat3 g_normal;
flat out mat3x2 g_uv;
flat out vec3 g_depth;
flat out int g_face;

void main() {
    for (int i = 0; i < 3; ++i) {
        gl_Position = gl_in[i].gl_Position;
        g_bary = vec3(i == 0, i == 1, i == 2);
        g_world = mat3(vs_world[0], vs_world[1], vs_world[2]);
        g_normal = mat3(vs_normal[0], vs_normal[1], vs_normal[2]);
        g_uv = mat3x2(vs_uv[0], vs_uv[1], vs_uv[2]);
        g_depth = vec3(vs_depth[0], vs_depth[1], vs_depth[2]);
        g_face = gl_PrimitiveIDIn;
        EmitVertex();
    }
    EndPrimitive();
}
