#version 330
// Presents the offscreen render over the background colour: accumulated colour, and in alpha the
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
out vec4 frag;

void main() {
    vec4 c = texture(image, v_uv);
#ifdef COLOR_SCALE
    c.rgb *= COLOR_SCALE;  // blend into a normalized target holds the colour over COLOR_SCALE
#endif
#ifdef COVERAGE_ALPHA
    vec3 rgb = c.rgb + (1.0 - c.a) * background;
#elif defined(UNORM_T)
    vec3 rgb = c.rgb + (c.a > 0.5 ? 2.0 * c.a - 1.0 : 2.0 * c.a) * background;  // 0.5 + 0.5 T, 0.5 T once stopped
#else
    vec3 rgb = c.rgb + abs(c.a) * background;
#endif
#ifdef MASK
    float m = clamp(texture(mask, v_uv).r, 0.0, 1.0);
    rgb = mix(rgb, mask_color, 0.55 * m);
#endif
    frag = vec4(clamp(rgb, 0.0, 1.0), 1.0);
}
