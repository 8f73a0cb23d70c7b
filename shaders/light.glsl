// Inverse-square fall-off of a point light (glsynth.lighting.falloff_gain): 1 with no
// falloff distance, else (d0 / d)^2 with d clipped below at FALLOFF_NEAREST times d0
// (defined by the renderer from glsynth.lighting.FALLOFF_NEAREST).
float falloff_gain(float dist, float d0) {
    if (d0 <= 0.0) return 1.0;
    float r = d0 / max(dist, FALLOFF_NEAREST * d0);
    return r * r;
}

// Ambient share of a surface facing `up` (+Y component of its normal) under a room
// light whose floor gives `ground` of the ceiling's (glsynth.lighting.ambient_gain).
float ambient_gain(float up, float ground) {
    return (ground + (1.0 - ground) * (0.5 + 0.5 * up)) * (2.0 / (1.0 + ground));
}

// Beam of a spot-like light (glsynth.lighting.beam_gain): cos(angle between the ray from
// the light and beam.xyz)^beam.w, the cosine floored at 1e-6; 1 when beam.w is 0.
float beam_gain(vec3 to_light, vec4 beam) {
    if (beam.w <= 0.0) return 1.0;
    float c = max(-dot(to_light, beam.xyz) / max(length(to_light), 1e-20), 1e-6);
    return pow(c, beam.w);
}

// Share of a point light's direct intensity reaching the surface
// (glsynth.lighting.direct_gain): fall-off times beam.
float direct_gain(vec3 to_light, float d0, vec4 beam) {
    return falloff_gain(length(to_light), d0) * beam_gain(to_light, beam);
}
