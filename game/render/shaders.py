"""GLSL programs (OpenGL 3.3 core): lit meshes, lines, flat 2-D shapes, text, and a triangle-id pass.

Meshes are lit by a headlight (the light sits at the eye) with two-sided diffuse shading, so scanned
meshes with inconsistent winding still read well; `u_shading` picks smooth (per-vertex normals,
recomputed after deformation), flat (face normals from screen-space derivatives) or unlit.
"""

MESH_VS = """
#version 330
uniform mat4 u_mvp;
uniform mat4 u_model;
uniform mat3 u_normal_mat;
in vec3 in_pos;
in vec3 in_normal;
out vec3 v_normal;
out vec3 v_world;
void main() {
    gl_Position = u_mvp * vec4(in_pos, 1.0);
    v_world = (u_model * vec4(in_pos, 1.0)).xyz;
    v_normal = u_normal_mat * in_normal;
}
"""

MESH_FS = """
#version 330
uniform vec4 u_color;
uniform vec3 u_eye;
uniform int u_shading;  // 0 smooth, 1 flat, 2 unlit
in vec3 v_normal;
in vec3 v_world;
out vec4 f_color;
void main() {
    if (u_shading == 2) { f_color = u_color; return; }
    vec3 n = u_shading == 1 ? cross(dFdx(v_world), dFdy(v_world)) : v_normal;
    float len = length(n);
    n = len > 1e-20 ? n / len : vec3(0.0, 0.0, 1.0);
    vec3 l = normalize(u_eye - v_world);
    float diff = abs(dot(n, l));
    // diff^40 by squaring (diff^32 * diff^8): pow() is an exp2/log2 pair, a sixth of a software
    // renderer's time on a see-through head (`chainsim bench render --pack prp`)
    float d2 = diff * diff;
    float d8 = d2 * d2;
    d8 = d8 * d8;
    float d32 = d8 * d8;
    d32 = d32 * d32;
    float spec = d32 * d8 * 0.25;
    f_color = vec4(u_color.rgb * (0.28 + 0.72 * diff) + vec3(spec), u_color.a);
}
"""

ID_FS = """
#version 330
uniform uint u_slot;
out vec4 f_color;
void main() {
    // triangle index + 1 in RGB (24 bits), the mesh slot in A: exact through an RGBA8 target
    uint t = uint(gl_PrimitiveID) + 1u;
    f_color = vec4(float(t & 255u), float((t >> 8) & 255u), float((t >> 16) & 255u), float(u_slot)) / 255.0;
}
"""

LINE_VS = """
#version 330
uniform mat4 u_mvp;
in vec3 in_pos;
void main() { gl_Position = u_mvp * vec4(in_pos, 1.0); }
"""

LINE_FS = """
#version 330
uniform vec4 u_color;
out vec4 f_color;
void main() { f_color = u_color; }
"""

FLAT2D_VS = """
#version 330
uniform vec2 u_screen;
in vec2 in_pos;
in vec4 in_color;
out vec4 v_color;
void main() {
    gl_Position = vec4(in_pos / u_screen * 2.0 - 1.0, 0.0, 1.0);
    v_color = in_color;
}
"""

FLAT2D_FS = """
#version 330
in vec4 v_color;
out vec4 f_color;
void main() { f_color = v_color; }
"""

TEXT_VS = """
#version 330
uniform vec2 u_screen;
in vec2 in_pos;
in vec2 in_uv;
in vec4 in_color;
out vec2 v_uv;
out vec4 v_color;
void main() {
    gl_Position = vec4(in_pos / u_screen * 2.0 - 1.0, 0.0, 1.0);
    v_uv = in_uv;
    v_color = in_color;
}
"""

TEXT_FS = """
#version 330
uniform sampler2D u_atlas;
in vec2 v_uv;
in vec4 v_color;
out vec4 f_color;
void main() { f_color = vec4(v_color.rgb, v_color.a * texture(u_atlas, v_uv).r); }
"""

# a cached viewport image copied pixel for pixel into its rectangle (chainsim.game.render.viewcache)
COPY_VS = """
#version 330
in vec2 in_pos;
void main() { gl_Position = vec4(in_pos, 0.0, 1.0); }
"""

COPY_FS = """
#version 330
uniform sampler2D u_image;
uniform ivec2 u_origin;
out vec4 f_color;
void main() { f_color = texelFetch(u_image, ivec2(gl_FragCoord.xy) - u_origin, 0); }
"""

# the same with its depth, so that items drawn over a cached layer are hidden where it is nearer
COPY_DEPTH_FS = """
#version 330
uniform sampler2D u_image;
uniform sampler2D u_depth;
uniform ivec2 u_origin;
out vec4 f_color;
void main() {
    ivec2 p = ivec2(gl_FragCoord.xy) - u_origin;
    f_color = texelFetch(u_image, p, 0);
    gl_FragDepth = texelFetch(u_depth, p, 0).r;
}
"""
