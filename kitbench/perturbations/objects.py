"""The task's object made bigger or smaller, heavier or lighter, more or less slippery."""

from __future__ import annotations

from sapien import physx

from kitbench.errors import KitbenchError
from kitbench.perturbations.base import Perturbation
from kitbench.perturbations.registry import register_perturbation


def _body(env) -> physx.PhysxRigidDynamicComponent:
    return env.target_object.find_component_by_type(physx.PhysxRigidDynamicComponent)


@register_perturbation
class ObjectScale(Perturbation):
    name = "object_scale"
    unit = "%"
    description = (
        "the task's object built `level` % larger (negative: smaller) in every dimension, its density kept; the "
        "task's success test measures the object as built"
    )
    minimum, maximum = -50.0, 100.0

    def check(self, env):
        if not env.supports_object_scale:
            raise KitbenchError(
                f"perturbation {self.name} is not supported by {type(env).__name__}: its object is not built to "
                f"measure (tasks that support it set supports_object_scale)"
            )

    def object_scale(self):
        return 1.0 + self.level / 100.0


@register_perturbation
class ObjectMass(Perturbation):
    name = "object_mass"
    unit = "%"
    description = "the task's object `level` % heavier (negative: lighter), its inertia scaled alike"
    minimum, maximum = -90.0, 1000.0

    def objects(self, env, rng):
        body = _body(env)
        factor = 1.0 + self.level / 100.0
        # a uniformly denser body: mass and inertia scale together, the centre of mass stays
        inertia = body.inertia * factor
        body.mass = body.mass * factor
        body.inertia = inertia


@register_perturbation
class ObjectFriction(Perturbation):
    name = "object_friction"
    unit = "%"
    description = (
        "the static and dynamic friction of the task's object `level` % higher (negative: lower); a contact "
        "uses the lower of its two bodies' coefficients"
    )
    minimum, maximum = -100.0, 1000.0

    def objects(self, env, rng):
        factor = 1.0 + self.level / 100.0
        for shape in _body(env).collision_shapes:
            old = shape.physical_material
            shape.physical_material = physx.PhysxMaterial(
                old.static_friction * factor, old.dynamic_friction * factor, old.restitution
            )
