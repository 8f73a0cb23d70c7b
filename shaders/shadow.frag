#version 330 core
// Depth only: the shadow map is the depth attachment.
void main() {
}
