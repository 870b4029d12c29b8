"""The light of the shadow and shaded passes, read from the scene: its first sun or point
light, in the object's local space, and the world's colour."""

import numpy as np

from ..inference.secondary import Light
from ..inference.shading import Lighting


def _lights(scene):
    """``scene``'s sun and point light objects, in ``scene.objects`` order."""
    for light in scene.objects:
        if light.type == "LIGHT" and light.data.type in ("SUN", "POINT"):
            yield light


def scene_light(scene, obj):
    """``Light`` of ``scene``'s first sun or point light (in ``scene.objects`` order) in the
    local space of ``obj``, else the default direction (``settings.DEFAULT_LIGHT_DIRECTION``,
    already in local space)."""
    return _scene_light(scene, obj)[1]


def _scene_light(scene, obj):
    """(the Blender light object or None, ``scene_light``)."""
    inverse = np.array(obj.matrix_world.inverted(), np.float64)
    for light in _lights(scene):
        matrix = np.array(light.matrix_world, np.float64)
        if light.data.type == "SUN":            # a sun shines down its local -Z
            towards = inverse[:3, :3] @ matrix[:3, 2]
            if np.linalg.norm(towards) > 0:
                return light, Light(direction=tuple(towards / np.linalg.norm(towards)),
                                    source=f"sun '{light.name}'")
            continue
        position = inverse[:3, :3] @ matrix[:3, 3] + inverse[:3, 3]
        return light, Light(direction=None, position=tuple(position),
                            source=f"point light '{light.name}'")
    return None, Light()


def world_colour(scene):
    """The linear colour of ``scene``'s world as a uniform sky: its Background node's colour
    times its strength where the World Output takes an unlinked Background, else the world's
    viewport colour (a textured sky is taken as that); black without a world."""
    world = scene.world
    if world is None:
        return (0.0, 0.0, 0.0)
    if world.use_nodes and world.node_tree is not None:
        output = next((node for node in world.node_tree.nodes
                       if node.type == "OUTPUT_WORLD" and node.is_active_output), None)
        surface = None if output is None else output.inputs["Surface"]
        if surface is not None and surface.is_linked:
            node = surface.links[0].from_node
            if node.type == "BACKGROUND" and not node.inputs["Color"].is_linked and not (
                    node.inputs["Strength"].is_linked):
                strength = float(node.inputs["Strength"].default_value)
                return tuple(max(0.0, float(c) * strength)
                             for c in node.inputs["Color"].default_value[:3])
    return tuple(max(0.0, float(c)) for c in world.color)


def scene_lighting(scene, obj):
    """The shaded pass's ``Lighting`` of ``scene`` for ``obj``: its first sun's strength
    (irradiance, W/m^2) or point light's power (W) and colour, its world's colour
    (``world_colour``) and the object's world units per local unit (the cube root of its
    world matrix's determinant: exact for a uniform scale); without a sun or point light
    the default direction and strength."""
    light, towards = _scene_light(scene, obj)
    linear = np.array(obj.matrix_world, np.float64)[:3, :3]
    scale = float(abs(np.linalg.det(linear)) ** (1.0 / 3.0)) or 1.0
    world = world_colour(scene)
    if light is None:
        return Lighting(light=towards, world=world, unit_scale=scale)
    return Lighting(light=towards, strength=float(light.data.energy),
                    colour=tuple(float(c) for c in light.data.color), world=world,
                    unit_scale=scale)


def scene_secondary(scene, obj, **settings):
    """The ``SecondarySettings`` (AO ``settings``: samples, distance) of the shadow and
    shaded passes lit as ``scene`` is now for ``obj`` (``scene_lighting``)."""
    from ..inference.secondary import SecondarySettings

    lighting = scene_lighting(scene, obj)
    return SecondarySettings(light=lighting.light, lighting=lighting, **settings)
