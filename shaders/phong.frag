#version 330 core
// Textured Phong shading with point lights, in the same form as glsynth.diff.shade:
//   colour = texel * sum(ambient + diffuse * max((n.l + wrap) / (1 + wrap), 0))
//            + sum(specular * ks * max(r.v, 0)^shininess)
// where the specular term is zero when the light is behind the surface (n.l <= 0) and
// wrap (material wrap lighting, 0 = Lambert) lets diffuse light reach past the terminator.
// Colours are display-referred: lighting acts on the sRGB-encoded texture values
// directly, as in the DermSynth3D paper's PyTorch3D renderer. Alpha is coverage.
#define MAX_LIGHTS 8
uniform sampler2D u_texture;
uniform vec3 u_eye;
uniform int u_num_lights;
uniform vec3 u_light_pos[MAX_LIGHTS];
uniform vec3 u_light_ambient[MAX_LIGHTS];
uniform vec3 u_light_diffuse[MAX_LIGHTS];
uniform vec3 u_light_specular[MAX_LIGHTS];
uniform vec3 u_mat_specular;
uniform float u_shininess;
uniform float u_wrap;   // 0 unless set (glsynth.lighting.material_uniforms)

#include "surface.glsl"

out vec4 out_color;

void main() {
    vec3 b = surface_bary();
    vec2 uv = g_uv * b;
    vec3 world = g_world * b;
    vec3 normal = g_normal * b;
    vec3 texel = texture(u_texture, vec2(uv.x, 1.0 - uv.y)).rgb;
    float nlen = length(normal);
    vec3 n = nlen > 0.0 ? normal / nlen : vec3(0.0);
    vec3 to_eye = u_eye - world;
    vec3 view_dir = to_eye / max(length(to_eye), 1e-20);
    vec3 light_sum = vec3(0.0);
    vec3 spec_sum = vec3(0.0);
    for (int i = 0; i < u_num_lights; ++i) {
        vec3 to_light = u_light_pos[i] - world;
        vec3 l = to_light / max(length(to_light), 1e-20);
        float cos_nl = dot(n, l);
        light_sum += u_light_ambient[i] + u_light_diffuse[i] * max((cos_nl + u_wrap) / (1.0 + u_wrap), 0.0);
        if (cos_nl > 0.0) {
            vec3 r = 2.0 * cos_nl * n - l;
            float rv = max(dot(r, view_dir), 0.0);
            spec_sum += u_light_specular[i] * u_mat_specular * pow(rv, u_shininess);
        }
    }
    out_color = vec4(clamp(texel * light_sum + spec_sum, 0.0, 1.0), 1.0);
}
