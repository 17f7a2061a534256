#version 330
// Per-Gaussian preprocessing, one fragment per drawn splat (runs on all rasteriser threads).
// Fragment k (k = y * row + x) projects Gaussian order[k], the k-th nearest visible Gaussian,
// so the splat pass reads its data at texel k with no index indirection.
// Input: the static Gaussian texture, `texels` texels per Gaussian, `row` Gaussians per row:
//   texel 0: mean xyz (world m), opacity
//   texels 1-3: rotation matrix rows r0, r1, r2 (xyz) and the scales (w), metres
//   texel 4..: owner (float), then the SH coefficients, flat index 1 + k * 3 + channel
// Output (one texel per splat, `row` per row), zero radius = culled:
//   center: u, v (pixels, image rows downward), major and minor radius of the alpha >= 1/255
//           ellipse (pixels)
//   conic:  inverse 2D covariance a, b, c (q = a dx^2 + 2 b dx dy + c dy^2), opacity
//   color:  SH colour rgb, owner
// Rules follow particlesplat.render: EWA with the Jacobian's x/z, y/z clamped to the frustum
// widened by 30%, +0.3 px^2 dilation, footprint alpha >= 1/255, near/far culling, and the
// determinant of the 2D covariance computed without cancellation (as particlesplat.projection).

uniform sampler2D gaussians;
uniform isampler2D order;  // sorted Gaussian indices, `row` per row
uniform int num;           // splats to project (the sorted list's length)
uniform int row;
uniform int texels;
uniform int sh_bases;
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
    if (z <= near_far.x || z >= near_far.y || opacity < 1.0 / 255.0) { cull(); return; }

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
    // alpha >= 1/255  <=>  q <= 2 ln(255 opacity)
    float qmax = 2.0 * log(255.0 * opacity);
    float mid = 0.5 * (a + c);
    float disc = sqrt(max(mid * mid - det, 0.0));
    float l1 = mid + disc;
    float l2 = max(mid - disc, 0.0);
    vec2 uv = vec2(intr.x * pc.x / z + intr.z, intr.y * pc.y / z + intr.w);

    // view-dependent colour
    vec3 d = normalize(mean - cam_center);
    float x = d.x, y = d.y, zz = d.z;
    float basis[16];
    basis[0] = C0;
    if (sh_bases > 1) {
        basis[1] = -C1 * y; basis[2] = C1 * zz; basis[3] = -C1 * x;
    }
    if (sh_bases > 4) {
        float xx = x * x, yy = y * y, z2 = zz * zz;
        basis[4] = C2[0] * x * y; basis[5] = C2[1] * y * zz; basis[6] = C2[2] * (2.0 * z2 - xx - yy);
        basis[7] = C2[3] * x * zz; basis[8] = C2[4] * (xx - yy);
        if (sh_bases > 9) {
            basis[9] = C3[0] * y * (3.0 * xx - yy); basis[10] = C3[1] * x * y * zz;
            basis[11] = C3[2] * y * (4.0 * z2 - xx - yy);
            basis[12] = C3[3] * zz * (2.0 * z2 - 3.0 * xx - 3.0 * yy);
            basis[13] = C3[4] * x * (4.0 * z2 - xx - yy); basis[14] = C3[5] * zz * (xx - yy);
            basis[15] = C3[6] * x * (xx - 3.0 * yy);
        }
    }
    vec3 rgb = vec3(0.0);
    int n = sh_bases * 3;
    vec4 blk = fetch(g, 4);
    float owner = blk.x;
    for (int j = 1; j <= n; ++j) {
        if (j % 4 == 0) blk = fetch(g, 4 + j / 4);
        rgb[(j - 1) % 3] += basis[(j - 1) / 3] * blk[j % 4];
    }
    rgb = max(rgb + 0.5, vec3(0.0));

    o_center = vec4(uv, sqrt(qmax * l1), sqrt(qmax * l2));
    o_conic = vec4(c / det, -b / det, a / det, opacity);
    o_color = vec4(rgb, owner);
}
