#version 330
// Per-Gaussian preprocessing, one fragment per drawn splat (runs on all rasteriser threads).
// Fragment k (k = y * row + x) projects Gaussian order[k], the k-th nearest visible Gaussian,
// so the splat pass reads its data at texel k with no index indirection.
// Input: the static Gaussian texture, `texels` texels per Gaussian, `row` Gaussians per row:
//   texel 0: mean xyz (world m), opacity
//   texels 1-3: rotation matrix rows r0, r1, r2 (xyz) and the scales (w), metres
//   texels 4 .. 4 + SH_BASES - 1: SH coefficient k (rgb) in texel 4 + k; texel 4 alpha = owner
// Output (one texel per splat, `row` per row), zero radius = culled:
//   center: u, v (pixels, image rows downward), major and minor radius of the alpha >= ALPHA_MIN
//           ellipse (pixels)
//   conic:  inverse 2D covariance a, b, c (q = a dx^2 + 2 b dx dy + c dy^2), opacity
//   color:  SH colour rgb, owner
// Rules follow particlesplat.render: EWA with the Jacobian's x/z, y/z clamped to the frustum
// widened by FOV_MARGIN, + dilation px^2, footprint alpha >= ALPHA_MIN (#defined from the
// library's constants), near/far culling, and the
// determinant of the 2D covariance computed without cancellation (as particlesplat.rendering.projection).

uniform sampler2D gaussians;
uniform isampler2D order;  // sorted Gaussian indices, `row` per row
uniform int num;           // splats to project (the sorted list's length)
uniform int row;
uniform int texels;
#ifndef SH_BASES
#define SH_BASES 1
#endif
uniform mat4 w2c;        // world -> camera (OpenCV), column-major as GLSL expects
uniform vec3 cam_center; // world
uniform vec4 intr;       // fx, fy, cx, cy (pixels)
uniform vec4 lim;        // x/z lower, x/z upper, y/z lower, y/z upper limits for the Jacobian
uniform vec2 near_far;
uniform float dilation;

layout(location = 0) out vec4 o_center;
layout(location = 1) out vec4 o_conic;
layout(location = 2) out vec4 o_color;

const float C0 = 0.28209479177387814;
const float C1 = 0.4886025119029199;
const float C2[5] = float[5](1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
                             -1.0925484305920792, 0.5462742152960396);
const float C3[7] = float[7](-0.5900435899266435, 2.890611442640554, -0.4570457994644658,
                             0.3731763325901154, -0.4570457994644658, 1.445305721320277,
                             -0.5900435899266435);

vec4 fetch(int g, int k) {
    return texelFetch(gaussians, ivec2((g % row) * texels + k, g / row), 0);
}

void cull() {
    o_center = vec4(0.0);
    o_conic = vec4(0.0);
    o_color = vec4(0.0);
}

void main() {
    ivec2 k = ivec2(gl_FragCoord.xy);
    if (k.y * row + k.x >= num) { cull(); return; }
    int g = texelFetch(order, k, 0).r;
    vec4 t0 = fetch(g, 0);
    vec4 t1 = fetch(g, 1);
    vec4 t2 = fetch(g, 2);
    vec4 t3 = fetch(g, 3);
    vec3 mean = t0.xyz;
    float opacity = t0.w;
    vec3 pc = (w2c * vec4(mean, 1.0)).xyz;
    float z = pc.z;
    if (z <= near_far.x || z >= near_far.y || opacity < ALPHA_MIN) { cull(); return; }

    // EWA: A = J W R S (2x3), Sigma2D = A A^T + dilation I; J at the clamped ray direction
    float xz = clamp(pc.x / z, lim.x, lim.y);
    float yz = clamp(pc.y / z, lim.z, lim.w);
    mat3 W = mat3(w2c);
    vec3 j0 = vec3(intr.x / z, 0.0, -intr.x * xz / z);
    vec3 j1 = vec3(0.0, intr.y / z, -intr.y * yz / z);
    vec3 s = vec3(t1.w, t2.w, t3.w);
    vec3 w0 = j0 * W;  // rows of J W (row vector times matrix)
    vec3 w1 = j1 * W;
    vec3 a0 = (w0.x * t1.xyz + w0.y * t2.xyz + w0.z * t3.xyz) * s;  // rows of A
    vec3 a1 = (w1.x * t1.xyz + w1.y * t2.xyz + w1.z * t3.xyz) * s;
    float sxx = dot(a0, a0), syy = dot(a1, a1), sxy = dot(a0, a1);
    // det(A A^T + eps I) = |cof(S) R^T W^T (j0 x j1)|^2 + eps tr(A A^T) + eps^2
    vec3 jc = (intr.x * intr.y / (z * z)) * vec3(xz, yz, 1.0);
    vec3 wc = jc * W;
    vec3 cr = wc.x * t1.xyz + wc.y * t2.xyz + wc.z * t3.xyz;
    vec3 cof = vec3(s.y * s.z, s.x * s.z, s.x * s.y);
    vec3 cc = cr * cof;
    float a = sxx + dilation;
    float c = syy + dilation;
    float b = sxy;
    float det = dot(cc, cc) + dilation * (sxx + syy) + dilation * dilation;
    // alpha >= ALPHA_MIN  <=>  q <= 2 ln(opacity / ALPHA_MIN)
    float qmax = 2.0 * log(opacity / ALPHA_MIN);
    float mid = 0.5 * (a + c);
    float disc = sqrt(max(mid * mid - det, 0.0));
    float l1 = mid + disc;
    float l2 = max(mid - disc, 0.0);
    vec2 uv = vec2(intr.x * pc.x / z + intr.z, intr.y * pc.y / z + intr.w);

    // view-dependent colour, unrolled for SH_BASES coefficients per channel (a compile-time
    // constant: dynamic indexing is slow on llvmpipe)
    vec3 d = normalize(mean - cam_center);
    float x = d.x, y = d.y, zz = d.z;
    vec4 t4 = fetch(g, 4);
    float owner = t4.w;
    vec3 rgb = C0 * t4.rgb;
#if SH_BASES > 1
    rgb += -C1 * y * fetch(g, 5).rgb + C1 * zz * fetch(g, 6).rgb - C1 * x * fetch(g, 7).rgb;
#endif
#if SH_BASES > 4
    float xx = x * x, yy = y * y, z2 = zz * zz;
    rgb += C2[0] * x * y * fetch(g, 8).rgb + C2[1] * y * zz * fetch(g, 9).rgb
         + C2[2] * (2.0 * z2 - xx - yy) * fetch(g, 10).rgb + C2[3] * x * zz * fetch(g, 11).rgb
         + C2[4] * (xx - yy) * fetch(g, 12).rgb;
#endif
#if SH_BASES > 9
    rgb += C3[0] * y * (3.0 * xx - yy) * fetch(g, 13).rgb + C3[1] * x * y * zz * fetch(g, 14).rgb
         + C3[2] * y * (4.0 * z2 - xx - yy) * fetch(g, 15).rgb
         + C3[3] * zz * (2.0 * z2 - 3.0 * xx - 3.0 * yy) * fetch(g, 16).rgb
         + C3[4] * x * (4.0 * z2 - xx - yy) * fetch(g, 17).rgb + C3[5] * zz * (xx - yy) * fetch(g, 18).rgb
         + C3[6] * x * (xx - 3.0 * yy) * fetch(g, 19).rgb;
#endif
    rgb = max(rgb + 0.5, vec3(0.0));

    o_center = vec4(uv, sqrt(qmax * l1), sqrt(qmax * l2));
    o_conic = vec4(c / det, -b / det, a / det, opacity);
    o_color = vec4(rgb, owner);
}
