#version 330 core
// Shared vertex stage. Triangles are drawn unindexed (three corners per face, in face
// order), so UV seams need no vertex splitting.
uniform mat4 u_view;
uniform mat4 u_proj;

in vec3 in_position;
in vec3 in_normal;
in vec2 in_uv;

out vec3 vs_world;
out vec3 vs_normal;
out vec2 vs_uv;
out float vs_depth;

void main() {
    vec4 view = u_view * vec4(in_position, 1.0);
    gl_Position = u_proj * view;
    vs_world = in_position;
    vs_normal = in_normal;
    vs_uv = in_uv;
    vs_depth = -view.z;  // view-space distance along the camera axis
}
