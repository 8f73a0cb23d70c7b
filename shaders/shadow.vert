#version 330 core
// Shadow map: distance from the main light to the nearest surface, seen from the light.
uniform mat4 u_view;
uniform mat4 u_proj;
uniform vec3 u_light;

in vec3 in_position;
out float v_dist;

void main() {
    gl_Position = u_proj * u_view * vec4(in_position, 1.0);
    v_dist = length(in_position - u_light);
}
