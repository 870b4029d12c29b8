"""The light of the shadow pass, read from the scene: its first sun or point light, in the
object's local space."""

import numpy as np

from ..inference.secondary import Light


def scene_light(scene, obj):
    """``Light`` of ``scene``'s first sun or point light (in ``scene.objects`` order) in the
    local space of ``obj``, else the default direction (``settings.DEFAULT_LIGHT_DIRECTION``,
    already in local space)."""
    inverse = np.array(obj.matrix_world.inverted(), np.float64)
    for light in scene.objects:
        if light.type != "LIGHT" or light.data.type not in ("SUN", "POINT"):
            continue
        matrix = np.array(light.matrix_world, np.float64)
        if light.data.type == "SUN":            # a sun shines down its local -Z
            towards = inverse[:3, :3] @ matrix[:3, 2]
            if np.linalg.norm(towards) > 0:
                return Light(direction=tuple(towards / np.linalg.norm(towards)),
                             source=f"sun '{light.name}'")
            continue
        position = inverse[:3, :3] @ matrix[:3, 3] + inverse[:3, 3]
        return Light(direction=None, position=tuple(position),
                     source=f"point light '{light.name}'")
    return Light()
