"""Names vulture (CI's dead-code check, [tool.vulture] in pyproject.toml) cannot see being used: a
framework calls or reads them by name, or the world digest reads them field by field. Each is read
here once, so vulture counts it as used; a name belongs here only with its reason."""

# ruff: noqa: B018 - each line is a bare attribute read, which is the point
from vulture.whitelist_utils import Whitelist

_ = Whitelist()

# pyglet calls a window's event handlers by name, with these arguments (game/trainer/window.py)
_.on_draw
_.on_key_press
_.on_key_release
_.on_mouse_drag
_.on_mouse_motion
_.on_mouse_press
_.on_mouse_release
_.on_mouse_scroll
_.on_resize
_.on_text
_.on_text_motion
_.modifiers
_.scroll_x

# moderngl applies these context settings when they are assigned (game/render)
_.blend_equation
_.blend_func
_.color_mask
_.compare_func
_.cull_face
_.depth_func
_.depth_mask

# set for the library that reads them: sqlite3's row factory, numpy's array flags, argparse's
# negative-number matcher, numba's @intrinsic signature (typingctx), a signal handler's signal number
_.row_factory
_.writeable
_._negative_number_matcher
_.typingctx
_.signum

# http.server calls a handler's do_POST and log_message (tests/server/test_xapi.py)
_.do_POST
_.log_message

# pytest reads pytest_plugins, and hands fixtures to the tests that name them as arguments
_.pytest_plugins
_.pytest_configure  # a hook pytest calls by name (tests/conftest.py)
_.gpu_always
_.monkeypatch_session

# component fields: part of the world digest (components/digest.py reads every field of a component),
# so a replay's digest covers them though no system reads them back
_.step_started  # needle ProcedureState
_.started_at  # needle ProcedureState
_.links_cut  # cutting Scissors

# event fields filled positionally and documented for pack code: Deformed(ent, moved, cut, added)
# (systems/tissue/deformation.py, docs/chainmail.md)
_.added_count

# result fields filled positionally: PathResult(u, status, iterations, load_steps, ...) of the study's
# nonlinear FEM (tools/study/fem_nonlinear.py)
_.load_steps

# a package's module-level __getattr__ (PEP 562): Python calls it for `from chainsim.systems.engine import make_body`
_.__getattr__

# jobs a spawned replay process runs by name ("replay_targets:sleepy"), tests/unit/test_replay_process.py
_.sleepy
_.crash

# the haptics' device port (chainsim.systems.engine.haptics.port): a driver is opened by the name DRIVERS
# gives as a string; OpenHaptics keeps only a pointer to the callback the Touch driver holds; a device
# reports its orientation though the needle reads only its depth; the servo keeps the device's own time
# of its last tick for a driver's diagnostics
_.open_touch
_._callback
_.orientation
_.device_clock
# the rating set a rater works on, named on the raters' pages (templates rate_list.html, rate_attempt.html)
_.set_name
# socketserver calls a request handler's handle() by name (tests/unit/test_delay_proxy.py)
_.handle
# socketserver reads these class attributes by name (tests/unit/test_delay_proxy.py)
_.daemon_threads
_.block_on_close

# pytest reads a test module's marks from a module-level variable of this name (tests marked slow)
_.pytestmark
