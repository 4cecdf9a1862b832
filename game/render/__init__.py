"""GL adapters (moderngl): contexts, shaders, GPU mesh buffers, the frame renderer, text and PNG output.

Only this package and `chainsim.game.trainer.window` import moderngl / pyglet; the rest of chainsim runs
without a display. The renderer draws one frame of a window layout - every viewport, the control
panel and the HUD - into whatever framebuffer it is given: a pyglet window's or an EGL off-screen one.
"""
