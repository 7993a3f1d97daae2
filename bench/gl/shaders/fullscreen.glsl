// Vertex stage of a full-screen pass: one triangle covering the viewport, from gl_VertexID.
#ifndef FULLSCREEN_GLSL
#define FULLSCREEN_GLSL
#if defined VERTEX_SHADER
void main() {
    vec2 p = vec2((gl_VertexID << 1) & 2, gl_VertexID & 2);
    gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}
#endif
#endif
