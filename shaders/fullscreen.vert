#version 330
// A full-viewport quad drawn as a 4-vertex triangle strip, no vertex buffers.
out vec2 v_uv;  // [0, 1]^2, GL orientation (y up)

void main() {
    vec2 p = vec2(float(gl_VertexID & 1), float((gl_VertexID >> 1) & 1));
    v_uv = p;
    gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}
