#version 330
// One splat per projected Gaussian, in front-to-back order: splat k reads texel k of the
// projection pass (see project.frag), so there is no index indirection.
// QUADS: an oriented rectangle around the alpha >= ALPHA_MIN ellipse, two triangles drawn through a
// static element buffer (vertices 4 k .. 4 k + 3). Otherwise a GL_POINTS sprite (vertex k) of
// the ellipse's bounding square (used only when every splat fits the driver's point size limit);
// points are drawn with the viewport widened by `guard` pixels on each side so that a sprite
// whose centre is off screen (points are clipped by their centre) still covers the image.
uniform sampler2D center_tex;
uniform sampler2D conic_tex;
uniform sampler2D color_tex;
uniform int row;
uniform vec2 size;          // image width, height in pixels
uniform float guard;        // viewport margin in pixels (points), 0 for quads
uniform int color_mode;     // 0 SH colour, 1 colour by owner, 2 colour by the owner's colour key
uniform float owner_key[MAX_KEYED];  // mode 2: owner k < MAX_KEYED takes the colour of owner owner_key[k]

flat out vec2 v_center;
flat out vec3 v_conic;
flat out float v_opacity;
flat out vec3 v_color;
flat out float v_owner;
#ifdef QUADS
smooth out vec2 v_w;  // the pixel in the ellipse's axes scaled by sqrt(conic eigenvalue): q = |v_w|^2
#endif

// particlesplat.core.palette: the PALETTE_* values are injected as #defines
vec3 owner_color(float owner) {
    if (owner < 0.0) return vec3(PALETTE_BACKGROUND);
    float h = fract(owner * PALETTE_HUE_STEP + PALETTE_HUE_OFFSET);
    vec3 k = clamp(abs(fract(h + vec3(0.0, 2.0 / 3.0, 1.0 / 3.0)) * 6.0 - 3.0) - 1.0, 0.0, 1.0);
    return mix(vec3(1.0), k, PALETTE_SATURATION) * PALETTE_VALUE;
}

void main() {
#ifdef QUADS
    int k = gl_VertexID >> 2;
#else
    int k = gl_VertexID;
#endif
    ivec2 tc = ivec2(k % row, k / row);
    vec4 c = texelFetch(center_tex, tc, 0);
    if (c.z <= 0.0) {           // culled: outside the clip volume
        gl_Position = vec4(2.0, 2.0, 2.0, 1.0);
        gl_PointSize = 1.0;
        return;
    }
    vec4 q = texelFetch(conic_tex, tc, 0);
    vec4 col = texelFetch(color_tex, tc, 0);
    v_center = c.xy;
    v_conic = q.xyz;
    v_opacity = q.w;
    v_owner = col.w;
    float key = color_mode == 2 && col.w >= 0.0 && col.w < float(MAX_KEYED) ? owner_key[int(col.w)] : col.w;
    v_color = color_mode >= 1 ? owner_color(key) : col.rgb;
#ifdef QUADS
    // major axis of the ellipse = eigenvector of the conic's smaller eigenvalue
    float mid = 0.5 * (q.x + q.z);
    float lmin = mid - sqrt(max(mid * mid - (q.x * q.z - q.y * q.y), 0.0));
    vec2 e1 = abs(q.y) > 1e-12 * max(q.x, q.z) ? normalize(vec2(q.y, lmin - q.x))
                                               : (q.x <= q.z ? vec2(1.0, 0.0) : vec2(0.0, 1.0));
    vec2 e2 = vec2(-e1.y, e1.x);
    vec2 s = vec2(float(gl_VertexID & 1), float((gl_VertexID >> 1) & 1)) * 2.0 - 1.0;
    // SPLAT_MARGIN (pixels) keeps pixel centres that round onto the ellipse boundary inside
    vec2 t = s * (c.zw + SPLAT_MARGIN);  // the corner along e1, e2 (pixels)
    vec2 p = c.xy + e1 * t.x + e2 * t.y;
    // q = d^T conic d for d = e1 t.x + e2 t.y is lambda1 t.x^2 + lambda2 t.y^2 (e1, e2 its eigenvectors), affine
    // in the pixel across the rectangle once scaled by the square roots: the fragments interpolate it
    float l1 = q.x * e1.x * e1.x + 2.0 * q.y * e1.x * e1.y + q.z * e1.y * e1.y;
    float l2 = q.x * e2.x * e2.x + 2.0 * q.y * e2.x * e2.y + q.z * e2.y * e2.y;
    v_w = t * sqrt(max(vec2(l1, l2), 0.0));
    gl_Position = vec4(p.x / size.x * 2.0 - 1.0, 1.0 - p.y / size.y * 2.0, 0.0, 1.0);  // guard is 0
#else
    vec2 ext = size + 2.0 * guard;
    gl_Position = vec4((c.x + guard) / ext.x * 2.0 - 1.0, 1.0 - (c.y + guard) / ext.y * 2.0, 0.0, 1.0);
    gl_PointSize = 2.0 * (c.z + SPLAT_MARGIN);
#endif
}
