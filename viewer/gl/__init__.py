"""What talks to OpenGL: the context's capabilities (:mod:`.caps`) and the splat renderer (:mod:`.renderer`:
its passes, offscreen framebuffers and readback). It imports the library only, never the rest of the viewer."""
