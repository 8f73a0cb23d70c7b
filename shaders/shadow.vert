#version 330 core
// Shadow map: the depth buffer of the scene seen from the main light.
uniform mat4 u_view;
uniform mat4 u_proj;

in vec3 in_position;

void main() {
    gl_Position = u_proj * u_view * vec4(in_position, 1.0);
}
