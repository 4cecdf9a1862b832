"""The trainer: a pack built into an App and run, headless, in the window or streamed to a browser tab.

Building and running (headless, plugins, input scripts and recordings), the seat's rules shared by the window
and the browser session (compiling, keytiming, frameloop, signin), the window (window, windowform, xvfb), and
the browser trainer (browser_session, browser_routes, frame_tiles).
"""
