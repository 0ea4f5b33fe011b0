"""A lean GLSL program for the avatar, installed into pyrender in place of its PBR mesh shader.

On a software rasteriser (llvmpipe, 2 cores) fragment shading dominates the frame. pyrender's
metallic-roughness shader evaluates GGX, Smith and Fresnel terms per light and inverts a 4x4
matrix per vertex; this one does wrapped Lambert, with a per-channel wrap where a material scatters
(skin: red light reaches past the shadow line, which warms the terminator as real skin does), a
Blinn-Phong highlight sized by the roughness and brightened at grazing angles (wet eyes and lips
glint), a base colour texture for avatars that bring one, and alpha-masked texels. It keeps
pyrender's uniform names, so pyrender's renderer drives it unchanged; two slots carry our own
parameters (see ``AvatarRenderer._primitive``). Colours follow pyrender's convention (light x
vertex colour, then gamma 2.2).
"""

from __future__ import annotations

import os
import re
from typing import Any

VERTEX = """#version 330 core
layout(location = 0) in vec3 position;
#ifdef NORMAL_LOC
layout(location = NORMAL_LOC) in vec3 normal;
#endif
#ifdef TEXCOORD_0_LOC
layout(location = TEXCOORD_0_LOC) in vec2 texcoord_0;
#endif
#ifdef COLOR_0_LOC
layout(location = COLOR_0_LOC) in vec4 color_0;
#endif
layout(location = INST_M_LOC) in mat4 inst_m;
uniform mat4 M;
uniform mat4 V;
uniform mat4 P;
out vec3 frag_position;
out vec3 frag_normal;
out vec2 uv_0;
out vec4 frag_color_in;
void main()
{
    mat4 model = M * inst_m;  // rigid: no non-uniform scale, so no inverse-transpose needed
    vec4 world = model * vec4(position, 1.0);
    gl_Position = P * V * world;
    frag_position = world.xyz;
#ifdef NORMAL_LOC
    frag_normal = mat3(model) * normal;
#else
    frag_normal = vec3(0.0, 0.0, 1.0);
#endif
#ifdef TEXCOORD_0_LOC
    uv_0 = texcoord_0;
#else
    uv_0 = vec2(0.0);
#endif
#ifdef COLOR_0_LOC
    frag_color_in = color_0;
#else
    frag_color_in = vec4(1.0);
#endif
}
"""

FRAGMENT = """#version 330 core
struct DirectionalLight { vec3 color; float intensity; vec3 direction; };
struct Material {
    vec3 emissive_factor;  // x: alpha cutoff of a masked texture (negative: none)
    vec4 base_color_factor;
    float metallic_factor;  // our skin scatter, 0..1 (this shader draws no metals)
    float roughness_factor;
#ifdef HAS_BASE_COLOR_TEX
    sampler2D base_color_texture;
#endif
};
uniform Material material;
uniform DirectionalLight directional_lights[MAX_DIRECTIONAL_LIGHTS];
uniform int n_directional_lights;
uniform vec3 cam_pos;
uniform vec3 ambient_light;
in vec3 frag_position;
in vec3 frag_normal;
in vec2 uv_0;
in vec4 frag_color_in;
out vec4 frag_color;
const float INV_PI = 0.31830988618;
// Skin lets red light travel under the surface: past the shadow line red fades last, blue first.
const vec3 SCATTER_WRAP = vec3(0.45, 0.25, 0.2);
const vec3 SCATTER_TINT = vec3(1.0, 0.9, 0.86);
void main()
{
    vec4 base = material.base_color_factor * frag_color_in;
#ifdef HAS_BASE_COLOR_TEX
    vec4 texel = texture(material.base_color_texture, uv_0);
    if (material.emissive_factor.x >= 0.0 && texel.a < material.emissive_factor.x) discard;
    base *= vec4(pow(texel.rgb, vec3(2.2)), texel.a);
#endif
    vec3 n = normalize(frag_normal);
    vec3 v = normalize(cam_pos - frag_position);
    if (dot(n, v) < 0.0 && !gl_FrontFacing) n = -n;  // the far side of a double-sided surface
    float scatter = clamp(material.metallic_factor, 0.0, 1.0);
    float rough = clamp(material.roughness_factor, 0.05, 1.0);
    float shininess = 2.0 / (rough * rough * rough * rough) - 1.5;
    float spec_scale = 0.04 * (shininess + 8.0) * 0.125 * INV_PI;
    float nv = max(dot(n, v), 0.0);
    float fresnel = 0.04 + 0.96 * pow(1.0 - nv, 5.0);
    vec3 sky = ambient_light * (0.75 + 0.25 * n.y);  // a little more from the sky than the floor
    vec3 diffuse_light = sky;
    vec3 spec_light = vec3(0.0);
    for (int i = 0; i < n_directional_lights; i++) {
        vec3 l = -directional_lights[i].direction;
        vec3 radiance = directional_lights[i].color * directional_lights[i].intensity;
        float ndl = dot(n, l);
        float plain = max((ndl + 0.15) / 1.15, 0.0);  // wrapped: a softer shadow edge
        vec3 wrapped = max((vec3(ndl) + SCATTER_WRAP) / (1.0 + SCATTER_WRAP), 0.0) * SCATTER_TINT;
        vec3 diffuse = mix(vec3(plain), wrapped, scatter);
        float spec = pow(max(dot(n, normalize(l + v)), 0.0), shininess) * spec_scale * max(ndl, 0.0);
        diffuse_light += radiance * 0.96 * INV_PI * diffuse;
        spec_light += radiance * spec * (1.0 + 4.0 * fresnel);
    }
    vec3 color = diffuse_light * base.rgb + spec_light;
    // skin and cloth catch a little light at grazing angles (the sheen of fine hair and fibre)
    color += sky * base.rgb * (0.25 * scatter + 0.1) * pow(1.0 - nv, 3.0);
    frag_color = vec4(pow(clamp(color, 0.0, 1.0), vec3(1.0 / 2.2)), 1.0);
}
"""

SOURCES = {"mesh.vert": VERTEX, "mesh.frag": FRAGMENT}


def install(renderer: Any) -> None:
    """Make a pyrender ``OffscreenRenderer`` draw meshes with this program (before its first render)."""
    import OpenGL.contextdata
    from pyrender import shader_program as sp

    class _Program(sp.ShaderProgram):
        def _load(self, shader_filename: str) -> str:
            name = os.path.basename(shader_filename)
            if name not in SOURCES:
                return super()._load(shader_filename)
            # resolve #ifdef NAME against pyrender's defines, then substitute their values, as pyrender does
            text = re.sub(
                r"#ifdef\s+([A-Za-z_][A-Za-z_0-9]*)\s*$",
                lambda m: "#if 1" if m.group(1) in self.defines else "#if 0",
                SOURCES[name],
                flags=re.MULTILINE,
            )
            for define, value in self.defines.items():
                text = text.replace(define, str(value))
            return text

    class _Cache(sp.ShaderProgramCache):
        """pyrender's cache, building ``_Program``s (same keys: one program per context and defines)."""

        def get_program(self, vertex_shader, fragment_shader, geometry_shader=None, defines=None):  # type: ignore[override]
            defines = dict(defines or {})
            files = [f for f in (vertex_shader, fragment_shader, geometry_shader) if f is not None]
            key = tuple(
                [OpenGL.contextdata.getContext()]
                + sorted([(os.path.basename(f), 1) for f in files] + list(defines.items()))
            )
            if key not in self._program_cache:
                paths = [
                    os.path.join(self.shader_dir, f) if f is not None else None
                    for f in (vertex_shader, fragment_shader, geometry_shader)
                ]
                self._program_cache[key] = _Program(
                    vertex_shader=paths[0], fragment_shader=paths[1], geometry_shader=paths[2], defines=defines
                )
            return self._program_cache[key]

    renderer._renderer._program_cache = _Cache()
