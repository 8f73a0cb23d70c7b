#version 330 core
// Box filter for k x k supersampling: each output pixel averages its k x k samples.
uniform sampler2D u_source;
uniform int u_factor;
out vec4 out_color;

void main() {
    ivec2 base = ivec2(gl_FragCoord.xy) * u_factor;
    vec4 acc = vec4(0.0);
    for (int y = 0; y < u_factor; ++y)
        for (int x = 0; x < u_factor; ++x)
            acc += texelFetch(u_source, base + ivec2(x, y), 0);
    out_color = acc / float(u_factor * u_factor);
}
