#version 330 core
// Shared vertex stage. Triangles are drawn unindexed (three corners per face, in face
// order), so the face id and the corner's barycentric come from gl_VertexID.
uniform mat4 u_view;
uniform mat4 u_proj;

in vec3 in_position;
in vec3 in_normal;
in vec2 in_uv;

out vec3 v_world;
out vec3 v_normal;
out vec2 v_uv;
out vec3 v_bary;
out float v_depth;
flat out int v_face;

void main() {
    vec4 view = u_view * vec4(in_position, 1.0);
    gl_Position = u_proj * view;
    v_world = in_position;
    v_normal = in_normal;
    v_uv = in_uv;
    int corner = gl_VertexID % 3;
    v_bary = vec3(corner == 0, corner == 1, corner == 2);
    v_depth = -view.z;               // view-space distance along the camera axis
    v_face = gl_VertexID / 3;
}
