"""The C-arm of the fluoroscopy view: where it points and what it has cost (thesis 3.2.3).

In theatre the foramen ovale is reached under X-ray, and every image adds radiation and time
(thesis 3.2.3), so the trainer counts them: single images ("shots"), seconds of continuous ("live")
fluoroscopy while the pedal is held, and an estimate of the patient's entrance dose from both.
`CArm` lives on a runtime entity "carm" so a replay reproduces its counts bit for bit.

Dose model (an estimate, shown so a trainee sees what each image costs): the entrance dose rate of a
mobile C-arm in normal fluoroscopy is about 0.2 mGy per second (a survey of published doses, J Appl
Clin Med Phys 2024;25:e14335), and a single image is taken as a SHOT_S burst at that rate.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import esper
import numpy as np

from chainsim.components.app import App
from chainsim.components.resources import EntityIndex
from chainsim.systems.procedures.procedure import XrayImage
from chainsim.systems.view.ui.viewports import carm_camera

#: entrance dose rate of continuous fluoroscopy, mGy per second
DOSE_RATE_MGY_S = 0.2
#: exposure time of one single image (a short burst), seconds
SHOT_S = 0.3
#: live fluoroscopy refreshes its image this often (pulsed fluoroscopy, pulses per second)
LIVE_RATE_HZ = 15.0
#: C-arm geometry of a mobile unit with a 23 cm (9 inch) image intensifier
SOURCE_TO_ISO_MM = 600.0
SOURCE_TO_DETECTOR_MM = 1000.0
DETECTOR_MM = 230.0


@dataclass(slots=True)
class CArm:
    """Pose and counts of the C-arm (runtime component on the entity "carm")."""

    azimuth_deg: float = 0.0  # see chainsim.systems.view.ui.viewports.carm_source_direction
    elevation_deg: float = 0.0
    iso: np.ndarray = field(default_factory=lambda: np.zeros(3))  # isocentre, world mm
    view: str = "lateral"  # the preset last chosen ("lateral", "submental"), or "free" once turned
    shots: int = 0  # single images this attempt
    live_s: float = 0.0  # seconds of live fluoroscopy this attempt
    live: bool = False  # the pedal is held now
    image_id: int = 0  # grows with every image the view must show (a shot, or a live pulse)
    image_pose: tuple = (0.0, 0.0, (0.0, 0.0, 0.0))  # (azimuth, elevation, iso) of the image shown
    attempt: int = 0  # the procedure attempt these counts belong to
    next_pulse_s: float = 0.0  # live time at which the next live image is due

    @property
    def exposure_s(self) -> float:
        """Seconds of X-ray this attempt: the shots' bursts plus the live time."""
        return self.shots * SHOT_S + self.live_s

    @property
    def dose_mgy(self) -> float:
        """Estimated entrance dose this attempt, mGy (module docstring)."""
        return self.exposure_s * DOSE_RATE_MGY_S


#: the C-arm's presets in words (the X-ray view's status line)
VIEW_NAMES = {"lateral": "Lateral", "submental": "Submental-oblique", "free": "Free angle"}


def xray_image(app: App) -> XrayImage | None:
    """The X-ray view's image request from the arm's pose at its last image, with its status line (the
    view, the arm's angles and what this attempt's X-ray has cost); None when the world has no C-arm."""
    index = app.get_resource(EntityIndex)
    carm = esper.try_component(index.get("carm"), CArm) if index is not None and index.get("carm") is not None else None
    if carm is None:
        return None
    az, el, iso = carm.image_pose
    status = (
        f"{VIEW_NAMES.get(carm.view, carm.view)} (az {carm.azimuth_deg:.0f}, el {carm.elevation_deg:.0f}) - "
        f"{carm.shots} image{'' if carm.shots == 1 else 's'}, {carm.exposure_s:.1f} s, {carm.dose_mgy:.2f} mGy"
    )
    return XrayImage(
        camera=carm_camera(az, el, iso, SOURCE_TO_ISO_MM, SOURCE_TO_DETECTOR_MM, DETECTOR_MM),
        image_id=carm.image_id,
        live=carm.live,
        attempt=carm.attempt,
        images=carm.shots + (1 if carm.live_s > 0 else 0),
        status=status,
        view=carm.view,
        azimuth_deg=float(az),
        elevation_deg=float(el),
    )
