// Included by the fragment shaders: the surface point a pixel sees.
in vec3 g_bary;
flat in mat3 g_world;
flat in mat3 g_normal;
flat in mat3x2 g_uv;
flat in vec3 g_depth;
flat in int g_face;

// At grazing angles the rasteriser's snapped vertices can put a covered pixel centre
// a hair outside its triangle; clamping keeps every attribute inside the face.
vec3 surface_bary() {
    vec3 b = clamp(g_bary, 0.0, 1.0);
    return b / (b.x + b.y + b.z);
}
