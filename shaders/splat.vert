#version 330
// One splat per Gaussian, reading the preprocessed per-Gaussian texels (see project.frag).
// QUADS: an oriented rectangle around the alpha >= 1/255 ellipse, two triangles drawn through a
// static element buffer (vertex 4 q + corner for the q-th splat); the Gaussian index of the q-th
// splat comes from the sorted order texture. Otherwise a GL_POINTS sprite whose vertex id is
// the Gaussian index (drawn through the sorted index buffer).
uniform sampler2D center_tex;
uniform sampler2D conic_tex;
uniform sampler2D color_tex;
uniform sampler2D axis_tex;
uniform int row;
uniform vec2 size;          // framebuffer width, height in pixels
uniform int color_mode;     // 0 SH colour, 1 colour by owner

#ifdef QUADS
uniform isampler2D order_tex;  // sorted Gaussian indices, ROW per row
#endif

flat out vec2 v_center;
flat out vec3 v_conic;
flat out float v_opacity;
flat out vec3 v_color;
flat out float v_owner;

vec3 owner_color(float owner) {
    if (owner < 0.0) return vec3(0.35);
    float h = fract(owner * 0.6180339887 + 0.11);
    vec3 k = clamp(abs(fract(h + vec3(0.0, 2.0 / 3.0, 1.0 / 3.0)) * 6.0 - 3.0) - 1.0, 0.0, 1.0);
    return mix(vec3(1.0), k, 0.75) * 0.95;
}

void main() {
#ifdef QUADS
    int q = gl_VertexID >> 2;
    int g = texelFetch(order_tex, ivec2(q % row, q / row), 0).r;
#else
    int g = gl_VertexID;
#endif
    ivec2 tc = ivec2(g % row, g / row);
    vec4 c = texelFetch(center_tex, tc, 0);
    if (c.w <= 0.0) {           // culled: outside the clip volume
        gl_Position = vec4(2.0, 2.0, 2.0, 1.0);
        gl_PointSize = 1.0;
        return;
    }
    vec4 k = texelFetch(conic_tex, tc, 0);
    vec4 col = texelFetch(color_tex, tc, 0);
    v_center = c.xy;
    v_conic = k.xyz;
    v_opacity = k.w;
    v_owner = col.w;
    v_color = color_mode == 1 ? owner_color(col.w) : col.rgb;
#ifdef QUADS
    vec4 ax = texelFetch(axis_tex, tc, 0);
    vec2 e1 = ax.xy;
    vec2 e2 = vec2(-e1.y, e1.x);
    vec2 s = vec2(float(gl_VertexID & 1), float((gl_VertexID >> 1) & 1)) * 2.0 - 1.0;
    // half a pixel of margin keeps pixel centres on the ellipse boundary inside
    vec2 p = c.xy + e1 * (s.x * (c.w + 0.5)) + e2 * (s.y * (ax.z + 0.5));
    gl_Position = vec4(p.x / size.x * 2.0 - 1.0, 1.0 - p.y / size.y * 2.0, 0.0, 1.0);
#else
    gl_Position = vec4(c.x / size.x * 2.0 - 1.0, 1.0 - c.y / size.y * 2.0, 0.0, 1.0);
    gl_PointSize = 2.0 * c.w + 1.0;
#endif
}
