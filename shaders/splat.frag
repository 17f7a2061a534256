#version 330
// Gaussian footprint alpha = min(ALPHA_MAX, opacity exp(-q / 2)), discarded below ALPHA_MIN,
// composited front to back as particlesplat.render (the constants are #defined from its Python
// constants). Two ways, chosen at run time (viewer/gl/caps.py):
//
// COMPOSITE_FETCH (GL_EXT_shader_framebuffer_fetch): the fragment reads its pixel, where
// attachment 0 alpha holds the transmittance T in front of this splat (cleared to 1); it adds
// T alpha (colour, or owner weights) and multiplies T by (1 - alpha). A pixel stops before the
// splat that would take T to <= T_MIN: T is then stored negated and later splats are discarded. UNORM_T
// (the colour pass into a normalized target, which holds [0, 1]): T is stored as 0.5 + 0.5 T, 0.5 T once stopped.
//
// Otherwise (core GL 3.3): the fragment writes premultiplied (alpha value, alpha) and fixed-function
// blending with factors (ONE_MINUS_DST_ALPHA, ONE) for colour and alpha adds T alpha value, where
// every attachment's alpha holds the coverage 1 - T (cleared to 0). There is no early stop: a
// pixel differs from the torch renderer's by at most T_MIN.
//
// Colour pass: rgb += T alpha colour. ID_PASS (ATTACH attachments): owner weights,
// attachment i channel c += T alpha [owner == owner_base + 3 i + c].
#ifdef COMPOSITE_FETCH
#extension GL_EXT_shader_framebuffer_fetch : require
#define OUT_QUALIFIER inout
#else
#define OUT_QUALIFIER out
#endif
flat in vec2 v_center;
flat in vec3 v_conic;
flat in float v_opacity;
flat in vec3 v_color;
flat in float v_owner;
#ifdef QUADS
smooth in vec2 v_w;
#endif

uniform vec2 size;
uniform int owner_base;

#ifndef ATTACH
#define ATTACH 1
#endif
#if ATTACH == 1
// (a size-1 inout array miscompiled on Mesa 22.3 llvmpipe: use a plain output)
layout(location = 0) OUT_QUALIFIER vec4 o_single;
#define OUT(i) o_single
#else
layout(location = 0) OUT_QUALIFIER vec4 o[ATTACH];
#define OUT(i) o[i]
#endif

void main() {
#ifdef FLAT_FRAGMENT
    // (profiling only: the same primitives with no footprint, no compositing; see viewer/bench/profile.py)
    OUT(0) = vec4(v_color, 1.0);
    return;
#endif
#ifdef QUADS
    float q = dot(v_w, v_w);  // (interpolated: the pixel centre in the ellipse's scaled axes)
#else
    vec2 d = vec2(gl_FragCoord.x, size.y - gl_FragCoord.y) - v_center;
    float q = v_conic.x * d.x * d.x + 2.0 * v_conic.y * d.x * d.y + v_conic.z * d.y * d.y;
#endif
    float a = min(ALPHA_MAX, v_opacity * exp(-0.5 * q));
#ifdef COMPOSITE_FETCH
#ifdef UNORM_T
    float T = 2.0 * OUT(0).a - 1.0;  // <= 0 once stopped
#else
    float T = OUT(0).a;
#endif
    if (a < ALPHA_MIN || T <= 0.0) discard;
    float t_next = T * (1.0 - a);
    if (t_next <= T_MIN) {
#ifdef UNORM_T
        OUT(0).a = 0.5 * T;
#else
        OUT(0).a = -T;
#endif
        return;
    }
    float w = T * a;
#ifdef ID_PASS
    float rel = v_owner - float(owner_base);
    for (int i = 0; i < ATTACH; ++i) {
        vec3 slot = vec3(float(3 * i), float(3 * i + 1), float(3 * i + 2));
        OUT(i).rgb += w * vec3(equal(slot, vec3(rel)));
    }
#else
    OUT(0).rgb += w * v_color;
#endif
#ifdef UNORM_T
    OUT(0).a = 0.5 + 0.5 * t_next;
#else
    OUT(0).a = t_next;
#endif
#else
    if (a < ALPHA_MIN) discard;
#ifdef ID_PASS
    float rel = v_owner - float(owner_base);
    for (int i = 0; i < ATTACH; ++i) {
        vec3 slot = vec3(float(3 * i), float(3 * i + 1), float(3 * i + 2));
        OUT(i) = vec4(a * vec3(equal(slot, vec3(rel))), a);
    }
#elif defined(COLOR_SCALE)
    OUT(0) = vec4(a * v_color / COLOR_SCALE, a);  // a normalized target: the colour over COLOR_SCALE
#else
    OUT(0) = vec4(a * v_color, a);
#endif
#endif
}
