// Included by the shading programs when SHADOWS is set: the main light's visibility
// from its shadow map at this fragment (mesh.vert hands each corner's lookup point).
uniform sampler2DShadow u_shadow_map;  // depth buffer seen from light 0 (compare <=)
flat in mat3x4 g_shadow_clip;

float main_light_visibility(vec3 b) {
    vec4 clip = g_shadow_clip * b;
    if (clip.w <= 0.0) return 1.0;
    vec3 at = clip.xyz / clip.w * 0.5 + 0.5;
    if (any(lessThan(at.xy, vec2(0.0))) || any(greaterThan(at.xy, vec2(1.0)))) return 1.0;
    // Four depth-compare lookups, each filtered bilinearly by the sampler over 2x2
    // texels: a smooth 4x4-texel percentage-closer filter for four fetches.
    vec2 texel = 1.0 / vec2(textureSize(u_shadow_map, 0));
    float ref = min(at.z, 1.0);
    return 0.25 * (texture(u_shadow_map, vec3(at.xy + vec2(-1.0, -1.0) * texel, ref))
                 + texture(u_shadow_map, vec3(at.xy + vec2( 1.0, -1.0) * texel, ref))
                 + texture(u_shadow_map, vec3(at.xy + vec2(-1.0,  1.0) * texel, ref))
                 + texture(u_shadow_map, vec3(at.xy + vec2( 1.0,  1.0) * texel, ref)));
}
