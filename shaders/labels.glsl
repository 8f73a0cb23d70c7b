// Integer labels, no lighting, no filtering, so ids (up to 65535) come back exactly.
// Each of the four slots holds either a label texture in UV space (sampled at the
// nearest texel) or, where u_per_corner is 1, per-face-corner labels (vertex labels
// laid out as face * 3 + corner in a 2D texture), giving each pixel the label of its
// face's corner with the largest barycentric weight (ties: the first, as numpy's argmax).
// Included by labels.frag and, with LABELS, by gbuffer.frag (one draw for both).
uniform usampler2D u_labels0;
uniform usampler2D u_labels1;
uniform usampler2D u_labels2;
uniform usampler2D u_labels3;
uniform int u_count;
uniform ivec4 u_per_corner;

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

uvec4 fetch_labels(vec2 uv, int face, vec3 b) {
    return uvec4(fetch(u_labels0, u_per_corner.x == 1, uv, face, b),
                 u_count > 1 ? fetch(u_labels1, u_per_corner.y == 1, uv, face, b) : 0u,
                 u_count > 2 ? fetch(u_labels2, u_per_corner.z == 1, uv, face, b) : 0u,
                 u_count > 3 ? fetch(u_labels3, u_per_corner.w == 1, uv, face, b) : 0u);
}
