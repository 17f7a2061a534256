#version 330
// Presents the offscreen render over the background colour (with SUPPORT_MAP, over the support surface's map where
// the pixel's ray meets it: particlesplat.model.support_map.support_map_image): accumulated colour, and in alpha the
// transmittance T (negated once a pixel stopped; with UNORM_T, a normalized target's 0.5 + 0.5 T and 0.5 T
// once stopped) or, with COVERAGE_ALPHA (blended path), 1 - T (and with COLOR_SCALE the colour over it);
// with MASK, tinting the pixels of a mask (weights of the selected particle, channel r). (A separate
// program: llvmpipe samples both sides of a uniform branch, and the mask's texture reads cost as much as
// the image's.)
in vec2 v_uv;
uniform sampler2D image;
uniform vec3 background;
#ifdef MASK
uniform sampler2D mask;
uniform vec3 mask_color;
#endif
#ifdef SUPPORT_MAP
uniform sampler2D support_map;  // RGB and support share, texel (0, 0) at world (-support_half, -support_half)
uniform mat3 cam_rot;           // the render camera's camera-to-world rotation (OpenCV axes)
uniform vec3 cam_eye;           // its centre, world metres
uniform vec4 intrinsics;        // fx, fy, cx, cy in pixels of image_size
uniform vec2 image_size;
uniform float support_z;
uniform float support_half;
uniform float edge_softness;

vec3 behind() {
    vec2 px = vec2(v_uv.x, 1.0 - v_uv.y) * image_size;  // OpenCV pixel coordinates (rows top down)
    vec3 d = cam_rot * vec3((px - intrinsics.zw) / intrinsics.xy, 1.0);
    if (d.z >= -1e-9 || cam_eye.z <= support_z) return background;
    vec2 xy = (cam_eye + (support_z - cam_eye.z) / d.z * d).xy / support_half;
    if (abs(xy.x) >= 1.0 || abs(xy.y) >= 1.0) return background;
    vec4 s = texture(support_map, xy * 0.5 + 0.5);
    return mix(background, s.rgb, clamp((s.a - 0.5) / edge_softness + 0.5, 0.0, 1.0));
}
#else
vec3 behind() { return background; }
#endif
out vec4 frag;

void main() {
    vec4 c = texture(image, v_uv);
#ifdef COLOR_SCALE
    c.rgb *= COLOR_SCALE;  // blend into a normalized target holds the colour over COLOR_SCALE
#endif
#ifdef COVERAGE_ALPHA
    vec3 rgb = c.rgb + (1.0 - c.a) * behind();
#elif defined(UNORM_T)
    vec3 rgb = c.rgb + (c.a > 0.5 ? 2.0 * c.a - 1.0 : 2.0 * c.a) * behind();  // 0.5 + 0.5 T, 0.5 T once stopped
#else
    vec3 rgb = c.rgb + abs(c.a) * behind();
#endif
#ifdef MASK
    float m = clamp(texture(mask, v_uv).r, 0.0, 1.0);
    rgb = mix(rgb, mask_color, 0.55 * m);
#endif
    frag = vec4(clamp(rgb, 0.0, 1.0), 1.0);
}
