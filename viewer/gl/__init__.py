"""What talks to OpenGL: the context's capabilities (:mod:`.caps`), the depth sort (:mod:`.depth_sort`), the
Gaussians and camera as the shaders read them (:mod:`.packing`), the shader sources (:mod:`.shaders`), the splat
renderer (:mod:`.renderer`: its passes, offscreen framebuffers and readback) and the blit into the window
(:mod:`.blit`). It imports the library only, never the rest of the viewer."""
