"""Haptics for the needle: the local contact model, the 1 kHz servo loop, the device port and a simulated device.

A force-feedback device wants a force every millisecond; the tissue simulation gives one every frame
(60 Hz). Between them sits a small local model of the needle's contact along its line (`model`): the
boundaries ahead of the tip with their stiffness and puncture force, the friction along the inserted
length, the bone or target the line meets, refreshed by the simulation each frame and evaluated by the
servo loop (`servo`) every tick. The tool is coupled to the hand through a spring-damper (virtual
coupling), so the needle stops at bone however hard the hand pushes and the force grows as it does.
`port` is the one interface a device driver fills in; `simdevice` is a device made of a trajectory and
a spring-mass hand, so everything runs and is tested without hardware. No ECS here: the needle
procedure attaches all this to a running scene (chainsim.systems.procedures.needle.haptics).
"""

#: the measures a pack's [metrics.NAME] can name that only a force-feedback device gives (no value without one)
DEVICE_MEASURES = ("device_peak_force", "puncture_force", "bone_contact_time")
#: an attempt's details that come from the device: the hand's forces are felt on the trainee's machine, and a
#: replay of the recording (depths, not the hand) cannot feel them again (chainsim.game.server.scoring)
DEVICE_DETAILS = ("device", "device_peak_force_N", "puncture_force_N", "bone_contact_s", "force_profile")
