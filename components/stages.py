"""Where each system runs: the App's stages in their fixed order and positions within a stage.

input -> simulation (needle/tool kinematics, collision, deformation) -> procedure (steps, assessment)
-> render. Systems with equal order run in the order they were added.
"""

STAGES = ("input", "simulation", "procedure", "render")

ORDER_INPUT = 0
ORDER_VIEW = 50  # cameras, picking, widgets (input stage)
ORDER_KINEMATICS = 100  # needle / tool pose (simulation stage)
ORDER_COLLISION = 200
ORDER_DEFORMATION = 300
ORDER_PROCEDURE = 100  # procedure steps (procedure stage)
ORDER_FLUORO = 150  # the C-arm: images and exposure, after the steps have begun an attempt
ORDER_ASSESSMENT = 200
ORDER_RENDER = 100
