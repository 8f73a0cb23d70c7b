// Integer labels, no lighting, no filtering, so ids (up to 65535) come back exactly.
// Slots 0 .. LABEL_MAPS-1 each hold a label map: a texture in UV space (sampled at the
// nearest texel) for slots below LABEL_CORNERS_FROM, per-face-corner labels (vertex
// labels laid out as face * 3 + corner in a 2D texture) from there on, giving each
// pixel the label of its face's corner with the largest barycentric weight (ties: the
// first, as numpy's argmax). The layout is compiled in (the renderer keeps one program
// per layout): llvmpipe evaluates both sides of a branch on a uniform, so a layout
// chosen at run time fetched every slot both ways.
// Included by labels.frag and, with LABELS, by gbuffer.frag (one draw for both).
#ifndef LABEL_MAPS
#define LABEL_MAPS 1
#endif
#ifndef LABEL_CORNERS_FROM
#define LABEL_CORNERS_FROM LABEL_MAPS
#endif
uniform usampler2D u_labels0;
uniform usampler2D u_labels1;
uniform usampler2D u_labels2;
uniform usampler2D u_labels3;

uint fetch(usampler2D tex, bool per_corner, vec2 uv, int face, vec3 b) {
    ivec2 size = textureSize(tex, 0);
    if (per_corner) {
        int corner = b.x >= b.y ? (b.x >= b.z ? 0 : 2) : (b.y >= b.z ? 1 : 2);
        int i = face * 3 + corner;
        return texelFetch(tex, ivec2(i % size.x, i / size.x), 0).r;
    }
    // v = 1 is the top row of the texture image, which is uploaded as row 0.
    ivec2 texel = ivec2(floor(vec2(uv.x, 1.0 - uv.y) * vec2(size)));
    return texelFetch(tex, clamp(texel, ivec2(0), size - 1), 0).r;
}

#ifdef DECAL_SLOT
// Lesion decals give the ids of slot DECAL_SLOT wherever the region map assigns one:
// lesion outlines at the decal's resolution (decal.glsl).
#define DECAL_IDS_ONLY
#include "decal.glsl"
#endif

uvec4 fetch_labels(vec2 uv, int face, vec3 b) {
    uvec4 labels = uvec4(0u);
    labels.x = fetch(u_labels0, 0 >= LABEL_CORNERS_FROM, uv, face, b);
#if LABEL_MAPS > 1
    labels.y = fetch(u_labels1, 1 >= LABEL_CORNERS_FROM, uv, face, b);
#endif
#if LABEL_MAPS > 2
    labels.z = fetch(u_labels2, 2 >= LABEL_CORNERS_FROM, uv, face, b);
#endif
#if LABEL_MAPS > 3
    labels.w = fetch(u_labels3, 3 >= LABEL_CORNERS_FROM, uv, face, b);
#endif
#ifdef DECAL_SLOT
    int layer = decal_layer(uv);
    if (layer >= 0) labels[DECAL_SLOT] = decal_id(layer, g_world * b);
#endif
    return labels;
}
