#version 330
#extension GL_EXT_shader_framebuffer_fetch : require
// Gaussian footprint, composited front to back exactly as particlesplat.render: the fragment
// reads its pixel (framebuffer fetch) where attachment 0 alpha holds the transmittance T in
// front of this splat (cleared to 1); it adds T alpha (colour, or owner weights) and multiplies
// T by (1 - alpha). A pixel stops before the splat that would take T to <= 1e-4: T is then
// stored negated and later splats are discarded.
// Colour pass: rgb += T alpha colour. ID_PASS (ATTACH attachments): owner weights,
// attachment i channel c += T alpha [owner == owner_base + 3 i + c].
flat in vec2 v_center;
flat in vec3 v_conic;
flat in float v_opacity;
flat in vec3 v_color;
flat in float v_owner;

uniform vec2 size;
uniform int owner_base;

#ifndef ATTACH
#define ATTACH 1
#endif
#if ATTACH == 1
// (a size-1 inout array miscompiled on Mesa 22.3 llvmpipe: use a plain output)
layout(location = 0) inout vec4 o_single;
#define OUT(i) o_single
#else
layout(location = 0) inout vec4 o[ATTACH];
#define OUT(i) o[i]
#endif

void main() {
    vec2 d = vec2(gl_FragCoord.x, size.y - gl_FragCoord.y) - v_center;
    float q = v_conic.x * d.x * d.x + 2.0 * v_conic.y * d.x * d.y + v_conic.z * d.y * d.y;
    float a = min(0.99, v_opacity * exp(-0.5 * q));
    float T = OUT(0).a;
    if (a < 1.0 / 255.0 || T <= 0.0) discard;
    float t_next = T * (1.0 - a);
    if (t_next <= 1e-4) {
        OUT(0).a = -T;
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
    OUT(0).a = t_next;
}
