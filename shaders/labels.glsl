// Integer label textures sampled at the nearest texel, no lighting, no filtering, so
// ids (up to 65535) come back exactly. Included by labels.frag and, with LABELS, by
// gbuffer.frag (one draw for the G-buffer and the labels).
uniform usampler2D u_labels0;
uniform usampler2D u_labels1;
uniform usampler2D u_labels2;
uniform usampler2D u_labels3;
uniform int u_count;

uint fetch(usampler2D tex, vec2 uv) {
    ivec2 size = textureSize(tex, 0);
    // v = 1 is the top row of the texture image, which is uploaded as row 0.
    ivec2 texel = ivec2(floor(vec2(uv.x, 1.0 - uv.y) * vec2(size)));
    return texelFetch(tex, clamp(texel, ivec2(0), size - 1), 0).r;
}

uvec4 fetch_labels(vec2 uv) {
    return uvec4(fetch(u_labels0, uv),
                 u_count > 1 ? fetch(u_labels1, uv) : 0u,
                 u_count > 2 ? fetch(u_labels2, uv) : 0u,
                 u_count > 3 ? fetch(u_labels3, uv) : 0u);
}
