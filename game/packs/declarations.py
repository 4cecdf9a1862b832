"""Declarations of every pack.toml section and key (format 1), registered in chainsim.components.registry.

The layout of a manifest:

    [pack]                  metadata and format version (one table)
    [settings]              declared run options (one table)
    [meshes.NAME]           a mesh file or a built-in primitive, with units and role
    [materials.NAME]        look and ChainMail softness
    [entities.NAME]         an entity; each sub-table is a component ([entities.NAME.transform] ...)
    [scenes.NAME]           which entities and which layout a run uses (PACK/SCENE on the CLI)
    [layouts.NAME]          viewports and control-panel widgets
    [[steps]]               the procedure's steps, in order
    [metrics.NAME]          what the assessment reports
    [docs.NAME]             pages shown in the app
    [points.NAME], [planes.NAME], [paths.NAME]   named anatomy (millimetres)

A procedure's own tables (the needle procedure's [needle_procedure], [roles.NAME], its target openings
and the rest), and the keys it adds to [[steps]] and [metrics.NAME] with their help, are declared with
the data they describe, in the procedure's folder (the needle procedure's manifest module,
docs/needle-procedures.md), and reach this table through each procedure's declaration
(chainsim.systems.procedures.PROCEDURES): nothing here names a procedure's vocabulary.
"""

from __future__ import annotations

from chainsim.components.registry import Field, Schema, section
from chainsim.systems.engine import limits
from chainsim.systems.engine.model_params import MATERIAL_KEYS, manifest_spec
from chainsim.systems.procedures import PROCEDURES  # importing it registers the procedures' sections
from chainsim.systems.procedures.verdicts import BENCHMARK_BASES

#: each procedure once (the table lists some under a former name too)
_PROCEDURES = [p for name, p in PROCEDURES.items() if name == p.name]

FORMAT_VERSION = 1
UNITS = ("mm", "cm", "m")
UNIT_SCALE_TO_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0}
PRIMITIVES = ("box", "sphere", "cylinder", "capsule", "cone", "grid", "tet_block")
#: the shell's viewport kinds, then those a procedure draws (the needle procedure's X-ray view, "fluoro")
VIEWPORT_KINDS = ("orbit", "attached", "panel", "fixed", *(k for p in _PROCEDURES for k in p.viewport_kinds))
WIDGET_KINDS = ("button", "toggle", "slider", "dial", "light", "text")

section(
    "pack",
    "table",
    "Pack metadata.",
    [
        Field("name", "str", help="Pack identifier used on the command line (letters, digits, - and _)."),
        Field("format", "int", help=f"Manifest format version; this chainsim reads format {FORMAT_VERSION}.", min=1),
        Field("title", "str", "", help="Human-readable title."),
        Field("version", "str", "0.1.0", help="The pack's own version."),
        Field("description", "str", "", help="One paragraph shown in `chainsim packs`."),
        Field("license", "str", "", help="Licence of the pack's own files (data carries its own, see attribution)."),
        Field("attribution", "path", "", help="File crediting third-party data in the pack."),
        Field("authors", "str_list", [], help="Authors of the pack."),
        Field(
            "includes",
            "str_list",
            [],
            help="Further TOML files in the pack whose tables are merged into this manifest.",
        ),
        Field(
            "requires",
            "str_list",
            [],
            help="Packs this one builds on; its paths may point into their folders as 'PACK:PATH' "
            '(e.g. path = "prp:meshes/skull.ply"). Nothing else of a required pack is read.',
        ),
        Field("default_scene", "str", "", help="Scene run when none is named (default: the first)."),
        Field(
            "procedure",
            "str",
            "",
            help="Procedure the pack uses: "
            + " or ".join(f"'{p.name}'" + (f" ({p.manifest.help})" if p.manifest.help else "") for p in _PROCEDURES)
            + "; empty for none.",
        ),
    ],
)

section(
    "settings",
    "table",
    "Run options; every key is declared here.",
    [
        Field(
            "dt", "float", 1.0 / 120.0, units="s", help="Fixed simulation step.", min=limits.MIN_DT, max=limits.MAX_DT
        ),
        Field("steps", "int", 600, help="Default number of steps for headless runs.", min=0, max=limits.MAX_STEPS),
        Field(
            "window_size",
            "vec2",
            [1280.0, 800.0],
            units="px",
            help="Initial window size.",
            min=1.0,
            max=limits.MAX_PIXELS,
        ),
        Field("background", "vec4", [0.08, 0.09, 0.11, 1.0], help="Clear colour (RGBA 0..1).", min=0.0, max=1.0),
    ],
)

section(
    "meshes",
    "named",
    "A mesh: a file in the pack or a built-in primitive.",
    [
        Field(
            "path",
            "path",
            "",
            help="Mesh file (.obj .ply .stl .off .glb for surfaces; .msh .vtk .vtu .mesh for tetrahedra).",
        ),
        Field("primitive", "enum", "", choices=("",) + PRIMITIVES, help="Built-in shape instead of a file."),
        Field(
            "display",
            "path",
            "",
            help="A lighter copy of the surface (same units) drawn in its place; picking, contacts and the "
            "C-arm image keep the full mesh. Ignored for meshes that deform.",
        ),
        Field(
            "inside",
            "str",
            "",
            help="Name of a closed mesh this one lies wholly inside (the skull in the skin): while an entity "
            "of that mesh with the same transform is drawn opaque and the eye is outside it, this one is "
            "not drawn, as none of it could show.",
        ),
        Field(
            "units",
            "enum",
            "mm",
            choices=UNITS,
            help="Units of the file's coordinates; everything is converted to millimetres.",
        ),
        Field("extents", "vec3", [10.0, 10.0, 10.0], units="mm", help="Box size, or grid/tet_block size.", min=0.0),
        Field("radius", "float", 5.0, units="mm", help="Sphere, cylinder, capsule or cone radius.", min=0.0),
        Field("height", "float", 10.0, units="mm", help="Cylinder, capsule or cone height (along +Z).", min=0.0),
        Field(
            "resolution",
            "vec3",
            [8.0, 8.0, 1.0],
            help="Elements per axis for grid / tet_block; sections for round shapes (the vertex count is "
            "checked against the mesh limits at validation).",
            min=1.0,
            max=limits.MAX_RESOLUTION,
        ),
        Field("merge_vertices", "bool", True, help="Merge duplicate vertices on load (surfaces)."),
        Field("reorder", "bool", False, help="Reorder vertices for memory locality (reverse Cuthill-McKee) on load."),
    ],
)

section(
    "materials",
    "named",
    "How an entity looks and, if deformable, how soft it is.",
    [
        Field("color", "vec4", [0.8, 0.8, 0.8, 1.0], help="RGBA 0..1.", min=0.0, max=1.0),
        Field("opacity", "float", 1.0, help="1 opaque, 0 invisible; blended back to front.", min=0.0, max=1.0),
        Field("wireframe", "bool", False, help="Draw the links instead of shaded faces."),
        Field("shading", "enum", "smooth", choices=("smooth", "flat", "unlit"), help="Lighting model."),
        Field(
            "attenuation",
            "float",
            0.0,
            units="1/mm",
            help="X-ray linear attenuation coefficient: how dark a closed mesh shows in the C-arm view (0: unseen).",
            min=0.0,
        ),
        Field(
            "preset",
            "str",
            "",
            help="Named ChainMail preset from assets/presets/materials.toml (overridden by explicit values).",
        ),
        # the ChainMail keys, declared with the model's parameters (chainsim.systems.engine.model_params)
        *(Field(key, **manifest_spec(key)) for key in MATERIAL_KEYS),
    ],
)

section(
    "scenes",
    "named",
    "A runnable selection of entities with a layout.",
    [
        Field("entities", "str_list", [], help="Entities spawned in this scene; empty means all."),
        Field("layout", "str", "", help="Layout used by the window and snapshots."),
        Field("description", "str", "", help="Shown in `chainsim packs`."),
        Field("script", "path", "", help="Input script that drives a headless run when none is given."),
    ],
)

VIEWPORT = Schema(
    "viewport",
    "One viewport of a layout.",
    (
        Field("name", "str", help="Viewport name (unique in the layout)."),
        Field(
            "kind",
            "enum",
            choices=VIEWPORT_KINDS,
            help=(
                "orbit: mouse-driven camera; attached: follows an entity and ignores input; panel: 2-D controls; "
                "fixed: a still camera; fluoro: the C-arm's radiograph (a drag turns the C-arm)."
            ),
        ),
        Field("rect", "rect", help="Placement [x, y, w, h] as window fractions, origin bottom-left.", min=0.0, max=1.0),
        Field("title", "str", "", help="Caption drawn in the viewport."),
        Field("target", "vec3", [0.0, 0.0, 0.0], units="mm", help="Point the camera looks at."),
        Field("distance", "float", 400.0, units="mm", help="Camera distance from target.", min=1e-3),
        Field(
            "yaw",
            "float",
            0.0,
            units="deg",
            help="Camera azimuth about +Z: at 0 the eye is on the +Y side looking along -Y; positive turns "
            "counter-clockwise.",
        ),
        Field(
            "pitch", "float", 0.0, units="deg", help="Camera elevation; positive raises the eye.", min=-89.9, max=89.9
        ),
        Field("fov", "float", 40.0, units="deg", help="Vertical field of view.", min=1.0, max=170.0),
        Field("near", "float", 1.0, units="mm", help="Near clip distance.", min=1e-6),
        Field("far", "float", 5000.0, units="mm", help="Far clip distance.", min=1e-3),
        Field(
            "attach",
            "entity",
            "",
            help="Entity the camera rides on (attached viewports): the eye sits at its origin plus offset and looks "
            "along its local +Z, local +Y up.",
        ),
        Field("offset", "vec3", [0.0, 0.0, 0.0], units="mm", help="Camera offset in the attached entity's frame."),
        Field("visible", "bool", True, help="Shown at start (a toggle widget may change it)."),
        Field("interactive", "bool", True, help="Whether camera input moves this view."),
        Field(
            "fit",
            "bool",
            False,
            help="orbit/fixed: frame the scene's meshes (and their pull paths) at start and when the window is "
            "resized: target and distance come from their bounds, yaw and pitch from this table.",
        ),
    ),
)

WIDGET = Schema(
    "widget",
    "One control-panel widget; using it emits a widget input event.",
    (
        Field("name", "str", help="Action name carried by the event (e.g. 'insert')."),
        Field("kind", "enum", choices=WIDGET_KINDS, help="Widget type."),
        Field("label", "str", "", help="Text on the widget."),
        Field("viewport", "str", "", help="Panel viewport that holds it (default: the first panel)."),
        Field(
            "rect",
            "rect",
            [0.0, 0.0, 0.0, 0.0],
            help="Placement in the panel as fractions (0 = automatic column layout).",
        ),
        Field("value", "any", False, help="Initial value (toggle: true/false; slider/dial: number)."),
        Field("min", "float", 0.0, help="Slider/dial minimum."),
        Field("max", "float", 1.0, help="Slider/dial maximum."),
        Field("step", "float", 0.0, help="Value change per key press or click (0: continuous)."),
        Field("key", "str", "", help="Keyboard shortcut (pyglet key name, e.g. 'i', 'left')."),
        Field("key_value", "float", 0.0, help="Value a key press sends (for buttons that step a dial)."),
        Field(
            "layer",
            "str",
            "",
            help="What a toggle switches: NAME shows/hides that layer ('planes' also the pack's planes), view:NAME a "
            "viewport, xray:NAME makes a layer see-through, wire:NAME draws it as links.",
        ),
        Field("help", "str", "", help="Tooltip / HUD help."),
    ),
)

section(
    "layouts",
    "named",
    "Viewports and widgets of a window.",
    [
        Field("viewports", "table_list", [], help="Array of viewport tables (see 'viewport').", item=VIEWPORT),
        Field("widgets", "table_list", [], help="Array of widget tables (see 'widget').", item=WIDGET),
    ],
)

section(
    "steps",
    "list",
    "Procedure steps, in order.",
    [
        Field("id", "str", help="Step identifier."),
        Field("title", "str", help="Short title shown in the HUD."),
        Field("instruction", "str", "", help="What the trainee does in this step."),
        Field(
            "fluoro_first_instruction",
            "str",
            "",
            help="Said instead of instruction in fluoroscopy-first mode (needle procedures' fluoro_first), for a "
            "step whose instruction leans on the tip view's target ring; empty: instruction.",
        ),
        Field("docs", "str", "", help="Docs page shown with this step."),
        Field(
            "done_on",
            "str_list",
            [],
            help=" ".join(["Events that complete this step.", *(p.manifest.done_on_help for p in _PROCEDURES)]).strip(),
        ),
        *(f for p in _PROCEDURES for f in p.manifest.step_fields),
        Field("open_docs", "bool", False, help="Open the step's docs page when the step begins."),
    ],
)

section(
    "metrics",
    "named",
    "A metric the assessment reports.",
    [
        Field("label", "str", help="Name shown to trainees and trainers."),
        Field("units", "str", "", help="Units of the value."),
        Field("help", "str", "", help="How it is computed (cite the method)."),
        Field("lower_is_better", "bool", True, help="Direction of improvement."),
        *(f for p in _PROCEDURES for f in p.manifest.metric_fields),
        Field(
            "benchmark",
            "float",
            None,
            help="Proficiency level in the metric's units: the debrief passes a value at or below it (at or "
            "above when lower_is_better is false). Absent: the metric is shown without a verdict.",
        ),
        Field(
            "benchmark_basis",
            "enum",
            "provisional",
            choices=BENCHMARK_BASES,
            help="What the benchmark rests on: published (a cited study; benchmark_source gives the publication, "
            "the figure and the population it describes), programme (the programme's own data, e.g. a study-report "
            "pass mark; benchmark_source says which data) or provisional (neither: the debrief and the records mark "
            "it so).",
        ),
        Field(
            "benchmark_source",
            "str",
            "",
            help="Where the benchmark comes from: the citation and population, the programme's data, or why it "
            "is provisional. Required with benchmark_basis published or programme.",
        ),
        Field(
            "critical",
            "float",
            None,
            help="A value beyond this (above it when lower is better) is a critical error that fails the attempt "
            "whatever the rest; so is no value at all (a needle that touched nothing).",
        ),
        Field("critical_note", "str", "", help="The critical error in words, as the debrief says it."),
        Field("advice", "str", "", help="One line of advice the debrief gives when the metric fails."),
    ],
)

section(
    "records",
    "table",
    'How a records server judges an upload of this pack (docs/limits.md, "Input a person can make").',
    [
        Field(
            "min_attempt_s",
            "float",
            0.0,
            units="s",
            help="The shortest time in which a person can make an attempt (aimed clicks and the tool's own travel "
            "at its top speed); a replayed attempt saved sooner is flagged for its trainer. 0: no minimum.",
            min=0.0,
            max=3600.0,
        ),
    ],
)

section(
    "docs",
    "named",
    "A documentation page shown in the app.",
    [
        Field("title", "str", help="Page title."),
        Field("path", "path", help="Markdown file in the pack."),
    ],
)

section(
    "points",
    "named",
    "A named point (millimetres, pack frame).",
    [
        Field("position", "vec3", units="mm", help="Position."),
        Field("help", "str", "", help="What the point marks."),
    ],
)

section(
    "planes",
    "named",
    "A named plane (millimetres, pack frame).",
    [
        Field("point", "vec3", units="mm", help="A point on the plane."),
        Field("normal", "vec3", help="Plane normal (normalised on use)."),
        Field("help", "str", "", help="What the plane is."),
    ],
)

section(
    "paths",
    "named",
    "A reference needle path.",
    [
        Field("entry", "vec3", units="mm", help="Skin entry point."),
        Field("target", "vec3", units="mm", help="Point aimed at."),
        Field("clear", "bool", False, help="Whether the straight path reaches the target before any bone."),
        Field("help", "str", "", help="Notes."),
    ],
)
