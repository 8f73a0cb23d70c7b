#version 330 core
// Shared vertex stage of the G-buffer, label and shading passes (see face.glsl).
#include "face.glsl"

void main() {
    emit_face();
    gl_Position = clip_position();
    // view-space distance along the camera axis of each corner: minus view z
    vec4 to_depth = -vec4(u_view[0][2], u_view[1][2], u_view[2][2], u_view[3][2]);
    g_depth = vec3(dot(to_depth, vec4(in_p0, 1.0)), dot(to_depth, vec4(in_p1, 1.0)),
                   dot(to_depth, vec4(in_p2, 1.0)));
}
