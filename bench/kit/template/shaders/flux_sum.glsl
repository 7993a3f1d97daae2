// One step of the reflected-flux reduction: output texel i holds the sum over row
// i * u_row_step of u_input, every u_column_step-th texel, times u_weight. The method applies it
// twice: the shared RSM atlas's rows into one row of row sums (every stride-th row and texel,
// weighted stride^2), then that row into a single texel, the total flux the lights' first
// bounce reflects (W, RGB). Each invocation loops over one row only: Mesa llvmpipe stops a
// shader invocation after 65535 loop iterations in total (bench/gl/context.py).
#include "fullscreen.glsl"
uniform sampler2D u_input;
uniform int u_row_step;
uniform int u_column_step;
uniform float u_weight;

#if defined FRAGMENT_SHADER
layout(location = 0) out vec4 out_sum;
void main() {
    int row = int(gl_FragCoord.x) * u_row_step;
    int width = textureSize(u_input, 0).x;
    vec3 sum = vec3(0.0);
    for (int x = 0; x < width; x += u_column_step)
        sum += texelFetch(u_input, ivec2(x, row), 0).rgb;
    out_sum = vec4(sum * u_weight, 1.0);
}
#endif
