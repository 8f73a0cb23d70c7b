// Included by the vertex shaders: every corner of the unindexed corner buffer carries
// its whole face (three positions, normals and UVs; corner k of face f is vertex
// 3 f + k), so the vertex stage hands fragments the face's corners flat and the
// fragment stage interpolates with clamped barycentrics exactly as glsynth.diff does
// (surface.glsl). This replaced a geometry shader, which llvmpipe runs at ~1 ms per
// 27k-face draw.
in vec3 in_p0;
in vec3 in_p1;
in vec3 in_p2;

uniform mat4 u_view;
uniform mat4 u_proj;

int face_corner() { return gl_VertexID % 3; }

vec3 corner_position() {
    int k = face_corner();
    return k == 0 ? in_p0 : (k == 1 ? in_p1 : in_p2);
}

// Every pass that shares a depth buffer or is compared pixel for pixel (G-buffer,
// labels, shading, depth-only) must place corners identically: one expression, and
// invariant so that the compiler cannot reorder it differently per program.
invariant gl_Position;

vec4 clip_position() { return u_proj * (u_view * vec4(corner_position(), 1.0)); }

#ifndef POSITION_ONLY
in vec3 in_n0;
in vec3 in_n1;
in vec3 in_n2;
in vec2 in_uv0;
in vec2 in_uv1;
in vec2 in_uv2;

out vec3 g_bary;
flat out mat3 g_world;
flat out mat3 g_normal;
flat out mat3x2 g_uv;
flat out vec3 g_depth;
flat out vec4 g_plane;  // the face's plane in view space: unit normal, n . p (gbuffer.frag)
flat out int g_face;
#ifdef HAIR_COORDS
in vec2 in_h0;
in vec2 in_h1;
in vec2 in_h2;
in vec3 in_ht;
flat out mat3x2 g_hair;   // hair-flow coordinates of the corners (skin.frag)
flat out vec3 g_hair_t;   // the surface a unit of t covers at the corners
#endif
#ifdef OCCLUSION
in vec3 in_ao;
flat out vec3 g_ao;       // ambient occlusion at the corners (Mesh.occlusion; skin.frag)
#endif

// Sets every output but gl_Position and g_depth; returns this corner's UV.
vec2 emit_face() {
    int k = face_corner();
    g_bary = vec3(k == 0, k == 1, k == 2);
    g_world = mat3(in_p0, in_p1, in_p2);
    g_normal = mat3(in_n0, in_n1, in_n2);
    g_uv = mat3x2(in_uv0, in_uv1, in_uv2);
    g_face = gl_VertexID / 3;
#ifdef HAIR_COORDS
    g_hair = mat3x2(in_h0, in_h1, in_h2);
    g_hair_t = in_ht;
#endif
#ifdef OCCLUSION
    g_ao = in_ao;
#endif
    return g_uv[k];
}
#endif
