#version 330 core
// Skin shading (Material.model "skin"), the torch twin is glsynth.diff.skin. In linear
// light (the sRGB texture is decoded, the result encoded again):
//   colour = albedo * sum(ambient + E * diffuse) + sum(E * specular),  E = light.diffuse
// * diffuse: wrap lighting that reaches further past the terminator in red than in
//   blue, on a normal whose micro-relief is softer in red than in blue (light scattered
//   under the skin blurs sub-millimetre relief more at long wavelengths); a lesion's
//   relief (decals: domes, ulcer walls, scale) is millimetres to centimetres across and
//   shades every channel alike, as the surface's own shape does;
// * specular: one GGX lobe with Smith masking and Schlick's Fresnel (F0 0.028, skin's
//   refractive index 1.4); sebum (the per-body oiliness map) sharpens and raises it;
// * ambient: the room's, times the share of it the body lets reach the point (per-vertex
//   ambient occlusion, glsynth.gl.occlusion; 1 for meshes without).
// With DETAIL, micro-detail that no body texture could hold (glsynth.assets.detail):
// the relief tile projected from the world position along the two axes nearest the
// normal, at two scales (furrows and pores as a normal perturbation and cavity
// darkening), the mesoscale tile along the same axes (undulation and mottling at
// millimetres to centimetres), and with HAIR, hair strands from the hair tile in
// per-vertex hair-flow coordinates, shaded as fibres (Kajiya-Kay) and casting a short
// parallax shadow, and wrinkles from the crease tile laid across the hair flow. All are
// scaled by the per-body skin parameters (u_params) and by the texture's alpha, the
// detail weight: 0 on non-skin, so clothing, scalp hair and eyes get none. Tiles are
// sampled at an explicit level of detail from the pixel's footprint on the surface, so
// far views see their average and never alias. Scalp hair (painted as non-skin; its
// coverage is the texture's alpha negated) is shaded as a mass of fibres, with strands
// at the pixel's own scale from noise stretched along the hair flow (scalp_strands).
#ifndef NUM_LIGHTS
#define NUM_LIGHTS 1
#endif
#ifndef SHADOWS
#define SHADOWS 0
#endif
#ifndef DETAIL
#define DETAIL 0
#endif
#ifndef HAIR
#define HAIR 0
#endif
#ifndef DECALS
#define DECALS 0
#endif
#define PI 3.14159265
#define F0 0.028
#define HAIR_RATIO 1.618   // scale of the second hair layer
#define FLAKE vec3(0.84, 0.81, 0.76)   // keratin flakes of dry skin, linear (sRGB 236, 232, 226: white scale)
uniform sampler2D u_texture;       // sRGB albedo, alpha = detail weight
uniform vec3 u_eye;
uniform vec3 u_light_pos[NUM_LIGHTS];
uniform vec3 u_light_ambient[NUM_LIGHTS];
uniform vec3 u_light_diffuse[NUM_LIGHTS];
uniform float u_light_falloff[NUM_LIGHTS];   // PointLight.falloff_distance (0: none)
uniform vec4 u_light_beam[NUM_LIGHTS];       // PointLight.beam: axis, exponent (0: none)
uniform float u_light_ground[NUM_LIGHTS];    // PointLight.ambient_ground (1: even)
uniform float u_roughness;         // GGX roughness of dry skin (alpha = roughness^2)
uniform float u_oil;               // 0..1, scales the oiliness map
uniform float u_wrap;              // Material.wrap
uniform float u_pixel_angle;       // footprint of a pixel per unit of depth
flat in vec3 g_ao;                 // ambient occlusion at the face's corners
#if DETAIL
uniform sampler2D u_params;        // R relief, G pores, B hair density, A lipids (oiliness or xerosis)
uniform float u_xerosis_codes;     // A below this is dry skin, above it sebum (detail.XEROSIS_CODES / 255)
uniform sampler2D u_flakes;        // xerosis flakes on the relief tile's texels: R opacity, G lifting
uniform float u_flake_patch_scale; // G is read this much larger (detail.FLAKE_PATCH_SCALE)
uniform sampler2D u_relief;        // relief tile (half floats): RG slope, B albedo change, A pore
uniform float u_relief_period;     // scene units per relief tile
uniform float u_relief_size;       // texels per relief tile
uniform float u_relief_amount;     // scales the relief (Material.relief)
uniform float u_pore_mean;         // mean of the relief tile's pore channel
uniform float u_macro_scale;       // the tile's second, coarser reading (detail.MACRO_SCALE)
uniform float u_macro_weight;      // and its share at relief level 0.5 (detail.MACRO_WEIGHT)
uniform sampler2D u_meso;          // mesoscale tile (half floats): RG slope, B melanin, A blood
uniform float u_meso_period;
uniform float u_meso_size;
#endif
#if HAIR
uniform sampler2D u_hair;          // hair tile: RG terminal, BA vellus coverage
uniform float u_hair_period;
uniform float u_hair_size;
uniform vec3 u_hair_rgb;           // sRGB colour of terminal hair
uniform float u_unit;              // scene units per metre
uniform sampler2D u_crease;        // crease tile (half floats): RG slope, B albedo change
uniform float u_crease_period;
uniform float u_crease_size;
uniform float u_coarse_crease_scale;   // the tile's second reading (detail.COARSE_CREASE_SCALE)
flat in mat3x2 g_hair;             // hair-flow coordinates (scene units) of the corners
flat in vec3 g_hair_t;             // the surface a unit of t covers at the corners (smooth)
#endif
#include "surface.glsl"
#include "light.glsl"

out vec4 out_color;

#if SHADOWS
#include "shadow.glsl"
#endif
#if DECALS
#include "decal.glsl"
#define DECAL_SLOPE 2.0     // decals.SLOPE_RANGE
#define DECAL_DETAIL 2.0    // decals.DETAIL_RANGE
#endif

#if DETAIL
// The world directions of a tile's u and v projected along world axis ``i``
void tile_axes(int i, out vec3 eu, out vec3 ev) {
    eu = i == 0 ? vec3(0.0, 0.0, 1.0) : vec3(1.0, 0.0, 0.0);
    ev = i == 1 ? vec3(0.0, 0.0, 1.0) : vec3(0.0, 1.0, 0.0);
}

// A tile's texel at point p, projected along the axes (eu, ev); none where the
// projection's weight is 0 (half the lookups wherever one projection suffices)
vec4 tile_at(sampler2D tile, float weight, vec3 p, vec3 eu, vec3 ev, float period, float lod) {
    return weight > 0.0 ? textureLod(tile, vec2(dot(p, eu), dot(p, ev)) / period, lod) : vec4(0.0);
}
#endif

#if HAIR
uniform float u_hair_curl;         // 0 straight .. 1 coily (SkinSurface.hair_curl)

float hash2(vec2 p) {
    vec3 q = fract(vec3(p.xyx) * 0.1031);
    q += dot(q, q.yzx + 33.33);
    return fract((q.x + q.y) * q.z);
}

// value noise in [-0.5, 0.5], smooth between the integer lattice points
float value_noise(vec2 p) {
    vec2 i = floor(p), f = p - i;
    f = f * f * f * (f * (6.0 * f - 15.0) + 10.0);   // quintic: no creases at the lattice
    return mix(mix(hash2(i), hash2(i + vec2(1.0, 0.0)), f.x),
               mix(hash2(i + vec2(0.0, 1.0)), hash2(i + vec2(1.0, 1.0)), f.x), f.y) - 0.5;
}

// Brightness of scalp hair strands (mean 0) at hair-flow point st (s along the hairs,
// t across, metres) for a pixel footprint of px metres: single hairs (70 um), bundles,
// locks, and clumps of 3 and 10 mm (curls and the locks that hair falls in, with deep
// shade between them: what makes a head of hair textured from a metre away, where a
// model trained on smooth hair called real hair skin), each octave faded out before a
// pixel spans its width, so that a far view keeps the texture's colour. Straight hair
// runs 40 widths along the flow before it changes; coily hair (u_hair_curl 1) is a mat
// of short, bent strands. Where the hair-flow coordinates stretch by ``stretched``
// (the skull's s is its true arc, so only where the head's capsule leaves the
// surface: nape, ears) single hairs would be drawn that much too long, so they fade
// out from 1.5; a lock or clump drawn a few times longer or narrower is still one, so
// those keep to 4. (t's scale, which narrows towards the crown, scalp_hair handles.)
const float STRAND_AMP[5] = float[5](0.55, 0.385, 0.27, 0.45, 0.3);
float scalp_strands(vec2 st, float px, float stretched) {
    float keep_fine = 1.0 - smoothstep(1.5, 3.0, stretched);
    float keep_clumps = 1.0 - smoothstep(4.0, 8.0, stretched);
    float stretch = mix(40.0, 1.5, u_hair_curl);
    float bend = mix(0.0005, 0.0003, u_hair_curl);       // lateral wander (m)
    float wave = mix(0.008, 0.002, u_hair_curl);         // over this length (m)
    float t = st.y + bend * value_noise(vec2(st.y / 0.002, st.x / wave));
    float v = 0.0;
    float width = 0.00007;
    for (int k = 0; k < 5; ++k) {
        float fade = (1.0 - smoothstep(0.4, 1.0, px / width)) * (k < 3 ? keep_fine : keep_clumps);
        if (fade > 0.0)
            v += fade * STRAND_AMP[k] * value_noise(vec2(t / width, st.x / (stretch * width)) + 17.0 * float(k));
        width *= 3.5;
    }
    return v;
}

// Scalp strands (scalp_strands) at hair-flow point st (metres) where a unit of t covers
// lt of surface (interpolated from the corners': per face it would jump). t narrows
// towards the crown as meridians do, and strands drawn on it would narrow to nothing,
// so t is rescaled by the two powers of sqrt(2) that bracket lt, each drawing strands
// at most sqrt(2) too wide or narrow, and the two sets are cross-faded (kept at full
// contrast: they are independent noise of mean 0). (lt is clamped where a degenerate
// face would scale t so far that float noise coordinates lose their fraction.)
float scalp_hair(vec2 st, float px, float stretched_s, float lt) {
    float level = -2.0 * log2(clamp(lt, 1e-3, 16.0));
    float j0 = floor(level);
    float w1 = smoothstep(0.0, 1.0, level - j0);
    float v = 0.0;
    for (int i = 0; i < 2; ++i) {
        float w = i == 0 ? 1.0 - w1 : w1;
        float j = j0 + float(i);
        if (w > 0.001)   // each scale its own strands: offsets of hundreds of hairs
            v += w * scalp_strands(vec2(st.x, st.y * exp2(-0.5 * j)) + vec2(0.023, 0.041) * j, px, stretched_s);
    }
    return v / sqrt((1.0 - w1) * (1.0 - w1) + w1 * w1);
}

// A hair fibre along unit vector fibre lit from l, seen from v (Kajiya-Kay): diffuse by
// the sine of the light to the fibre, and a specular cone (sine^40 of the half vector)
vec2 kajiya_kay(vec3 fibre, vec3 l, vec3 v) {
    float tl = dot(fibre, l);
    vec3 h = (l + v) / max(length(l + v), 1e-20);
    float th = dot(fibre, h);
    float s2 = max(1.0 - th * th, 0.0), s4 = s2 * s2, s16 = s4 * s4 * s4 * s4;
    return vec2(0.3 + 0.7 * sqrt(max(1.0 - tl * tl, 0.0)), 0.12 * (s16 * s4));
}
#endif

vec3 to_linear(vec3 c) {
    return mix(c / 12.92, pow((c + 0.055) / 1.055, vec3(2.4)), step(0.04045, c));
}

vec3 to_srgb(vec3 c) {
    return mix(c * 12.92, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(0.0031308, c));
}

// The unit normal of a surface (unit normal ng) raised by a height field whose gradient
// is grad (world units per world unit; its part along ng is dropped).
vec3 bumped(vec3 ng, vec3 grad) {
    vec3 nd = ng - (grad - ng * dot(ng, grad));
    return nd / max(length(nd), 1e-20);
}

void main() {
    vec3 b = surface_bary();
    vec2 uv = g_uv * b;
    vec3 world = g_world * b;
    vec3 normal = g_normal * b;
    float occlusion = dot(g_ao, b);
    float nlen = length(normal);
    vec3 ng = nlen > 0.0 ? normal / nlen : vec3(0.0);
    vec4 tex = texture(u_texture, vec2(uv.x, 1.0 - uv.y));
    vec3 albedo = to_linear(tex.rgb);
    vec3 to_eye = u_eye - world;
    vec3 v = to_eye / max(length(to_eye), 1e-20);
    vec3 n = ng;
    float oil = 0.5 * u_oil;
    float terminal = 0.0, vellus = 0.0, hair_shadow = 0.0;
    vec3 fibre = vec3(0.0);
    // footprint of this pixel on the surface (isotropic, as GL's own LOD)
    float footprint = dot(g_depth, b) * u_pixel_angle / max(abs(dot(ng, v)), 0.2);
    // (alpha below 0: scalp hair, its coverage)
    float detail_weight = max(tex.a, 0.0), scalp = max(-tex.a, 0.0), gloss = 0.0;
    // body hair keeps the surrounding skin's density over a lesion, a little thinned:
    // hairs rooted around it lie across it (a lesion's own smoothness is no reason for a
    // hairless patch, which real hairy skin does not show)
    float hair_weight = min(detail_weight, 1.0);
    vec3 grad = vec3(0.0);         // height gradient of relief and lesions, world units
    vec3 n_shape = ng;             // the surface's shape: its geometry and lesion relief
#if DECALS
    vec4 daux;
    vec3 dax, day;
    vec4 dcol = decal_colour(uv, world, footprint, daux, dax, day);
    albedo = mix(albedo, to_linear(dcol.rgb), dcol.a);
    detail_weight = mix(detail_weight, daux.a * DECAL_DETAIL, dcol.a);
    scalp *= 1.0 - dcol.a;
    hair_weight *= 1.0 - 0.3 * dcol.a;
    gloss = daux.b * dcol.a;
    vec2 dslope = (daux.xy * 255.0 - 128.0) / 127.0 * DECAL_SLOPE * dcol.a;
    grad += dslope.x * dax + dslope.y * day;
    n_shape = bumped(ng, grad);
#endif
#if DETAIL
    vec4 body_prm = texture(u_params, vec2(uv.x, 1.0 - uv.y));
    float skin_share = min(detail_weight, 1.0);
    vec4 prm = body_prm * skin_share;
    // the lipid axis: sebum above u_xerosis_codes, dry skin below it
    oil = clamp((body_prm.a - u_xerosis_codes) / (1.0 - u_xerosis_codes), 0.0, 1.0) * skin_share * u_oil;
    float dry = clamp(1.0 - body_prm.a / u_xerosis_codes, 0.0, 1.0) * skin_share;
    float lod = log2(max(footprint / u_relief_period * u_relief_size, 1e-6));
    // the tile projected along the two world axes nearest the normal (two lookups, not
    // three), each weighted by how much more it faces the normal than the third axis:
    // that weight is zero where the second and third change places, so no seam shows
    vec3 a = abs(ng);
    int lo = a.x <= a.y ? (a.x <= a.z ? 0 : 2) : (a.y <= a.z ? 1 : 2);
    int i1 = (lo + 1) % 3, i2 = (lo + 2) % 3;
    vec2 w = vec2(a[i1], a[i2]) - a[lo];
    w *= w;
    w *= w;
    w = w.x + w.y > 1e-12 ? w / (w.x + w.y) : vec2(0.5);
    // a projection with under 0.2% of the weight is left out (on most of the body)
    w = w.y < 0.002 ? vec2(1.0, 0.0) : (w.x < 0.002 ? vec2(0.0, 1.0) : w);
    vec3 u1, v1, u2, v2;
    tile_axes(i1, u1, v1);
    tile_axes(i2, u2, v2);
    vec4 p1 = tile_at(u_relief, w.x, world, u1, v1, u_relief_period, lod);
    vec4 p2 = tile_at(u_relief, w.y, world, u2, v2, u_relief_period, lod);
    // the same tile u_macro_scale times larger, offset: coarser furrows across several
    // plateaus, and the sum of two incommensurate periods does not repeat. They deepen
    // as the square of the relief level (0.5 on most skin): the coarse criss-cross
    // furrows of aged skin, knuckles and elbows, hardly any on a young face. Only their
    // slopes: the tile's albedo (dark furrow walls, each plateau a shade of its own) at
    // 2 mm cells painted a crackle glaze of dark lines and flat-toned polygons on
    // close-ups; a coarse furrow shows by its shading, as in a photograph
    float level = 2.0 * prm.r;
    float macro_w = u_macro_weight * min(level * level, 2.0);
    vec3 macro_at = world / u_macro_scale + vec3(0.37, 0.61, 0.23) * u_relief_period;
    float macro_lod = lod - log2(u_macro_scale);
    p1.rg += macro_w * tile_at(u_relief, w.x, macro_at, u1, v1, u_relief_period, macro_lod).rg;
    p2.rg += macro_w * tile_at(u_relief, w.y, macro_at, u2, v2, u_relief_period, macro_lod).rg;
    // at relief level 1 (0.5 in the map, most skin) the tile's own depths; lichenified
    // skin (detail weight above 1) deepens it
    float relief = level * u_relief_amount * max(detail_weight, 1.0);
    // the height gradient of each projection in world axes, blended, then kept in the
    // tangent plane (the surface gradient)
    grad += relief * (w.x * (p1.r * u1 + p1.g * v1) + w.y * (p2.r * u2 + p2.g * v2));
    // albedo: furrow darkening and melanin speckle (mean 0 over the tile), pores (their
    // mean darkening over the tile, u_pore_mean, given back so far views keep the colour)
    float tone = dot(w, vec2(p1.b, p2.b));
    float pore = dot(w, vec2(p1.a, p2.a));
    albedo *= (1.0 + min(relief, 1.0) * tone) * (1.0 - 0.6 * prm.g * (pore - u_pore_mean));
    // xerosis: keratin plates lifting in patches along the skin's lines, white at their
    // edges, and the dry horny layer a little dull and ashy everywhere (linear in the
    // flakes' opacity, so the mipmaps' average is what a far view should see)
    if (dry > 0.0) {
        float plates = w.x * tile_at(u_flakes, w.x, world, u1, v1, u_relief_period, lod).r
                       + w.y * tile_at(u_flakes, w.y, world, u2, v2, u_relief_period, lod).r;
        float patch_period = u_relief_period * u_flake_patch_scale;
        float patch_lod = lod - log2(u_flake_patch_scale);
        float lifting = w.x * tile_at(u_flakes, w.x, world, u1, v1, patch_period, patch_lod).g
                        + w.y * tile_at(u_flakes, w.y, world, u2, v2, patch_period, patch_lod).g;
        albedo = mix(albedo, FLAKE, dry * (0.02 + 0.3 * plates * (0.35 + 0.65 * smoothstep(0.3, 0.8, lifting))));
    }
    // the mesoscale tile along the same axes: the surface's soft undulation, and melanin
    // and blood mottling as absorbance (melanin absorbs more towards blue, blood in
    // green; blood shows less through more melanin, as in glsynth.assets.skin)
    float mlod = log2(max(footprint / u_meso_period * u_meso_size, 1e-6));
    // (its smooth features hide a quicker crossfade between the projections: weights
    // to the 16th power of the axes' lead, so that most pixels need one lookup)
    vec2 wm = w * w;
    wm *= wm;
    wm /= wm.x + wm.y;
    wm = wm.y < 0.002 ? vec2(1.0, 0.0) : (wm.x < 0.002 ? vec2(0.0, 1.0) : wm);
    // (faded out from 2 to 6 mm per pixel, mip levels 3.4-5, and not read beyond: its
    // centimetre undulation would otherwise vary from pixel to pixel in far views)
    float meso = 1.0 - smoothstep(3.4, 5.0, mlod);
    vec4 m1 = meso * tile_at(u_meso, meso * wm.x, world, u1, v1, u_meso_period, mlod);
    vec4 m2 = meso * tile_at(u_meso, meso * wm.y, world, u2, v2, u_meso_period, mlod);
    grad += relief * (wm.x * (m1.r * u1 + m1.g * v1) + wm.y * (m2.r * u2 + m2.g * v2));
    float pigment = dot(wm, vec2(m1.b, m2.b)), blood = dot(wm, vec2(m1.a, m2.a));
    float blood_shows = clamp(3.0 * albedo.g, 0.3, 1.0);
    albedo *= exp(-skin_share * (pigment * vec3(0.6, 0.85, 1.0)
                                              + blood_shows * blood * vec3(0.1, 1.0, 0.6)));
#if HAIR
    // hair-flow frame of this face: dp/ds (along the hairs) and dp/dt
    mat2 dh = mat2(g_hair[1] - g_hair[0], g_hair[2] - g_hair[0]);
    vec3 e1 = g_world[1] - g_world[0], e2 = g_world[2] - g_world[0];
    float det = determinant(dh);
    vec3 t_s = vec3(1.0, 0.0, 0.0), t_t = vec3(0.0, 1.0, 0.0);
    if (abs(det) > 1e-30) {
        mat2 inv = inverse(dh);
        t_s = e1 * inv[0][0] + e2 * inv[0][1];
        t_t = e1 * inv[1][0] + e2 * inv[1][1];
    }
    vec3 t_flat = t_s - n * dot(n, t_s);
    vec3 fibre_dir = t_flat / max(length(t_flat), 1e-20);
    vec2 hc = g_hair * b;
    float hlod = log2(max(footprint / u_hair_period * u_hair_size, 1e-6));
    // two layers of the tile at incommensurate scales and offsets (groups R, B from one,
    // G, A from the other), so that the tile's period does not show
    vec4 hs = textureLod(u_hair, hc / u_hair_period, hlod);
    vec4 hs2 = textureLod(u_hair, hc / (HAIR_RATIO * u_hair_period) + vec2(0.37, 0.61), hlod - log2(HAIR_RATIO));
    float dens = body_prm.b * hair_weight;
    float tv = clamp(dens * 4.0, 0.0, 1.0);
    float tt = clamp((dens - 0.25) / 0.75, 0.0, 1.0);
    terminal = hs.r * clamp(2.0 * tt, 0.0, 1.0) + hs2.g * clamp(2.0 * tt - 1.0, 0.0, 1.0);
    vellus = 0.5 * (hs.b + hs2.a) * tv;
    // parallax shadow: hairs lie ~0.15 mm above the skin; look up the hair that stands
    // between this point and the main light
    vec3 l0 = (u_light_pos[0] - world) / max(length(u_light_pos[0] - world), 1e-20);
    float lift = 0.00015 * u_unit / max(dot(ng, l0), 0.3);
    vec2 shift = lift * vec2(dot(l0, t_s) / max(length(t_s), 1e-20), dot(l0, t_t) / max(length(t_t), 1e-20));
    // (a level coarser: hairs stand at different heights and lights are not points, so
    // their shadows are soft)
    vec4 hsh = textureLod(u_hair, (hc + shift) / u_hair_period, hlod + 1.5);   // first layer only
    hair_shadow = 1.2 * hsh.r * clamp(tt, 0.0, 0.5) + 0.4 * hsh.b * tv;
    fibre = fibre_dir;
    float strands = 0.0;
    vec3 mass_fibre = fibre_dir;
    if (scalp > 0.0) {
        // scalp hair falls from the crown: down the head, projected on the surface
        // (smooth, where the hair-flow frame is flat per face and would show the
        // facets in its highlights); the frame only where the surface faces up
        vec3 down = vec3(0.0, -1.0, 0.0) - ng * -ng.y;
        float dl = length(down);
        mass_fibre = mix(fibre_dir, down / max(dl, 1e-20), smoothstep(0.15, 0.4, dl));
        mass_fibre /= max(length(mass_fibre), 1e-20);
        // how much s stretches here (a unit of it covers that much surface, or a
        // fraction); t's scale comes smooth from the corners
        float ls = length(t_s);
        strands = scalp_hair(hc / u_unit, footprint / u_unit, max(ls, 1.0 / max(ls, 1e-20)), dot(g_hair_t, b));
    }
    // wrinkles: the crease tile's grooves run along its x, laid along t (across the hair
    // flow: around a limb, across the forehead and neck). Fine ones where the relief
    // level rises above ordinary skin's (aged skin, dorsal hands, knuckles, elbows,
    // knees), and deep creases a few millimetres apart higher still. Each fades out
    // before a pixel covers its spacing: coarse mip levels of a tile of sparse lines
    // still vary from texel to texel, which a far view would show as blotches
    float px_mm = 1000.0 * footprint / u_unit;
    // (1.05: ordinary skin's 0.5 is 128 / 255 in the map)
    float fine_w = clamp((level - 1.05) / 0.95, 0.0, 1.0) * (1.0 - smoothstep(0.4, 1.2, px_mm));
    float coarse_w = clamp((level - 1.3) / 0.7, 0.0, 1.0)
                     * (1.0 - smoothstep(0.4 * u_coarse_crease_scale, 1.2 * u_coarse_crease_scale, px_mm));
    if (fine_w + coarse_w > 0.0) {
        vec2 cc = hc.yx / u_crease_period;
        float clod = log2(max(footprint / u_crease_period * u_crease_size, 1e-6));
        vec3 c = vec3(0.0);
        if (fine_w > 0.0)
            c = fine_w * textureLod(u_crease, cc, clod).rgb;
        if (coarse_w > 0.0)
            c += coarse_w * textureLod(u_crease, cc / u_coarse_crease_scale + vec2(0.29, 0.53),
                                       clod - log2(u_coarse_crease_scale)).rgb;
        // the tile's slopes along t and s to the world: the coordinates' gradients
        // (dp/dt / |dp/dt|^2 for near-orthogonal hair-flow coordinates)
        float a_c = u_relief_amount;
        grad += a_c * (c.r * t_t / max(dot(t_t, t_t), 1e-20) + c.g * t_s / max(dot(t_s, t_s), 1e-20));
        albedo *= 1.0 + a_c * c.b;
    }
#endif
#endif
    n = bumped(ng, grad);
    float roughness = mix(mix(u_roughness, 0.75 * u_roughness, oil), 0.2, gloss);
    float alpha = roughness * roughness;
    float a2 = alpha * alpha;
    float k = 0.5 * alpha;
    float nv = max(dot(n, v), 1e-4);
    vec3 wrap = u_wrap * vec3(1.0, 0.6, 0.45);
    vec3 light_sum = vec3(0.0);
    vec3 spec_sum = vec3(0.0);
    vec3 hair_light = vec3(0.0);
    vec3 hair_spec = vec3(0.0);
    vec3 mass_light = vec3(0.0);   // scalp hair: fibres that also shade as a surface
    vec3 mass_spec = vec3(0.0);
    for (int i = 0; i < NUM_LIGHTS; ++i) {
        vec3 to_light = u_light_pos[i] - world;
        vec3 l = to_light / max(length(to_light), 1e-20);
#if SHADOWS
        float vis = i == 0 ? main_light_visibility(b) : 1.0;
#else
        float vis = 1.0;
#endif
        vis *= direct_gain(to_light, u_light_falloff[i], u_light_beam[i]);
        float nl_detail = dot(n, l);
        float nl_geo = dot(n_shape, l);
        vec3 nl = mix(vec3(nl_detail), vec3(nl_geo), vec3(0.6, 0.3, 0.15));
        vec3 diffuse = max((nl + wrap) / (1.0 + wrap), 0.0);
        float shade = i == 0 ? 1.0 - 0.6 * clamp(hair_shadow, 0.0, 1.0) : 1.0;
        // (the surface's own normal: skin and hair alike, relief does not shade it)
        vec3 ambient = u_light_ambient[i] * ambient_gain(ng.y, u_light_ground[i]) * occlusion;
        light_sum += ambient + vis * shade * u_light_diffuse[i] * diffuse;
        if (nl_detail > 0.0) {
            vec3 h = (l + v) / max(length(l + v), 1e-20);
            float nh = max(dot(n, h), 0.0);
            float d = nh * nh * (a2 - 1.0) + 1.0;
            float D = a2 / (PI * d * d);
            float G = nl_detail / (nl_detail * (1.0 - k) + k) * nv / (nv * (1.0 - k) + k);
            // clamped: with the light at the eye (a flash) v.h rounds to just above 1
            float m = clamp(1.0 - dot(v, h), 0.0, 1.0), m2 = m * m;
            float F = F0 + (1.0 - F0) * (m2 * m2 * m);   // Schlick: m^5 (pow is slow on llvmpipe)
            spec_sum += vis * shade * u_light_diffuse[i] * (PI * D * F * G / (4.0 * nv) * (1.0 + 0.4 * oil + gloss));
        }
#if HAIR
        vec2 kk = kajiya_kay(fibre, l, v);
        hair_light += ambient + vis * u_light_diffuse[i] * kk.x;
        hair_spec += vis * u_light_diffuse[i] * kk.y;
        if (scalp > 0.0) {
            // a mass of hair is lit on the side facing the light; its far side is in
            // the shadow of the hairs in front (wrapped a little: light passes between)
            float facing = clamp((nl_geo + 0.25) / 1.25, 0.0, 1.0);
            kk = kajiya_kay(mass_fibre, l, v);
            mass_light += ambient + vis * facing * u_light_diffuse[i] * kk.x;
            mass_spec += vis * facing * u_light_diffuse[i] * kk.y;
        }
#endif
    }
    vec3 colour = albedo * light_sum + spec_sum;
#if HAIR
    if (scalp > 0.0) {   // dark gaps between strands, glints along the bright ones
        vec3 mass = albedo * max(1.0 + 1.6 * strands, 0.1) * mass_light
                    + 0.4 * mass_spec * clamp(1.0 + 3.0 * strands, 0.0, 3.0);
        // the hairline breaks up into the strands and clumps that end there (the
        // painted coverage fades over millimetres; labels keep it)
        colour = mix(colour, mass, clamp(scalp + 3.0 * scalp * (1.0 - scalp) * strands, 0.0, 1.0));
    }
    vec3 hair_albedo = to_linear(u_hair_rgb);
    vec3 vellus_albedo = mix(albedo, hair_albedo, 0.3) * 1.15;   // fine, partly translucent
    float cover = clamp(terminal + vellus, 0.0, 1.0);
    if (cover > 0.0) {
        vec3 hair_col = (hair_albedo * terminal + vellus_albedo * vellus) / max(terminal + vellus, 1e-6);
        colour = mix(colour, hair_col * hair_light + hair_spec, cover);
    }
#endif
    out_color = vec4(to_srgb(clamp(colour, 0.0, 1.0)), 1.0);
}
