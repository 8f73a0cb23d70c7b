#version 330 core
in float v_dist;
out float out_dist;

void main() {
    out_dist = v_dist;
}
