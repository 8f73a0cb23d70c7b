// Lesion decals (glsynth.pipeline.decals): each lesion at its own resolution. The body's
// region map names the decal (layer + 1) that covers a texel; the surface point is
// projected into that decal by its row of u_decal_info (a 3 x 4 projection to decal
// pixels, the decal's +x and +y axes in world space, its pixel size at the look-at
// point). Colours are sampled with an explicit level of detail from the pixel's
// footprint on the surface, like the skin detail tiles; ids at the nearest pixel.
uniform usampler2D u_decal_region;     // uint16 at the body texture's size
uniform sampler2D u_decal_info;        // RGBA32F, 5 x N: projection rows 0-2, axes, texel
#ifndef DECAL_IDS_ONLY
uniform sampler2DArray u_decal_colour; // sRGB + coverage
uniform sampler2DArray u_decal_aux;    // relief slope x, y, gloss, micro-relief visibility
#endif
uniform usampler2DArray u_decal_ids;   // lesion ids
uniform float u_decal_size;            // pixels per decal side

// The decal layer covering UV ``uv`` (-1: none).
int decal_layer(vec2 uv) {
    ivec2 size = textureSize(u_decal_region, 0);
    ivec2 t = clamp(ivec2(floor(vec2(uv.x, 1.0 - uv.y) * vec2(size))), ivec2(0), size - 1);
    return int(texelFetch(u_decal_region, t, 0).r) - 1;
}

// Decal pixel coordinates (column, row; centres at +0.5) of world point p in ``layer``.
vec2 decal_pixel(int layer, vec3 p) {
    vec4 h = vec4(p, 1.0);
    vec3 q = vec3(dot(texelFetch(u_decal_info, ivec2(0, layer), 0), h),
                  dot(texelFetch(u_decal_info, ivec2(1, layer), 0), h),
                  dot(texelFetch(u_decal_info, ivec2(2, layer), 0), h));
    return q.xy / q.z;
}

// The lesion id decal ``layer`` holds at world point p (0 outside it).
uint decal_id(int layer, vec3 p) {
    ivec2 px = ivec2(floor(decal_pixel(layer, p)));
    int n = int(u_decal_size);
    if (any(lessThan(px, ivec2(0))) || any(greaterThanEqual(px, ivec2(n)))) return 0u;
    return texelFetch(u_decal_ids, ivec3(px, layer), 0).r;
}

#ifndef DECAL_IDS_ONLY
// Colour (sRGB, coverage in a) and aux of the decal at world point p for a pixel whose
// footprint on the surface is ``footprint`` world units; coverage 0 outside decals.
// ``axis_x``/``axis_y`` get the decal's image axes in world space.
vec4 decal_colour(vec2 uv, vec3 p, float footprint, out vec4 aux, out vec3 axis_x, out vec3 axis_y) {
    aux = vec4(0.5, 0.5, 0.0, 0.5);
    axis_x = vec3(1.0, 0.0, 0.0);
    axis_y = vec3(0.0, 1.0, 0.0);
    int layer = decal_layer(uv);
    if (layer < 0) return vec4(0.0);
    vec2 st = decal_pixel(layer, p) / u_decal_size;
    if (any(lessThan(st, vec2(0.0))) || any(greaterThan(st, vec2(1.0)))) return vec4(0.0);
    vec4 ax = texelFetch(u_decal_info, ivec2(3, layer), 0);
    vec4 ay = texelFetch(u_decal_info, ivec2(4, layer), 0);
    axis_x = ax.xyz;
    axis_y = ay.xyz;
    float lod = log2(max(footprint / ax.w, 1e-6));
    aux = textureLod(u_decal_aux, vec3(st, float(layer)), lod);
    return textureLod(u_decal_colour, vec3(st, float(layer)), lod);
}
#endif
