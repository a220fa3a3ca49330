"""AV2's 30 cuboid categories mapped onto nuScenes' 23 categories and 8 attributes.

nuScenes code (colour maps, ``category_to_detection_name``) only knows its own names, so every
written annotation carries one of them. The table and the reasons for the judgement calls are
in ``docs/categories.md``; keep the two in sync.
"""

from __future__ import annotations

from dataclasses import dataclass

# nuScenes category name -> short description (our wording).
NUSCENES_CATEGORIES: dict[str, str] = {
    "animal": "Any animal.",
    "human.pedestrian.adult": "Adult pedestrian.",
    "human.pedestrian.child": "Child pedestrian.",
    "human.pedestrian.construction_worker": "Person whose main purpose in the scene is construction work.",
    "human.pedestrian.personal_mobility": "Person on a small personal vehicle (skateboard, scooter, segway).",
    "human.pedestrian.police_officer": "Police officer or person directing traffic.",
    "human.pedestrian.stroller": "Stroller, with or without a child.",
    "human.pedestrian.wheelchair": "Wheelchair, with or without its user.",
    "movable_object.barrier": "Barrier or post that keeps vehicles out of an area.",
    "movable_object.debris": "Debris on the road.",
    "movable_object.pushable_pullable": "Object a pedestrian pushes or pulls (cart, bin, small device).",
    "movable_object.trafficcone": "Traffic cone or barrel.",
    "static_object.bicycle_rack": "Bicycle rack.",
    "vehicle.bicycle": "Bicycle, with or without rider.",
    "vehicle.bus.bendy": "Articulated bus.",
    "vehicle.bus.rigid": "Rigid bus (and rail vehicles running in the street).",
    "vehicle.car": "Passenger car, van, SUV, pick-up.",
    "vehicle.construction": "Construction vehicle.",
    "vehicle.emergency.ambulance": "Ambulance.",
    "vehicle.emergency.police": "Police vehicle.",
    "vehicle.motorcycle": "Motorcycle or moped, with or without rider.",
    "vehicle.trailer": "Trailer pulled by a vehicle.",
    "vehicle.truck": "Truck, box truck, truck cab or other large vehicle.",
}

NUSCENES_ATTRIBUTES: dict[str, str] = {
    "cycle.with_rider": "A rider is on the bicycle or motorcycle.",
    "cycle.without_rider": "No rider is on the bicycle or motorcycle.",
    "pedestrian.moving": "The pedestrian is moving.",
    "pedestrian.sitting_lying_down": "The pedestrian is sitting or lying down.",
    "pedestrian.standing": "The pedestrian is standing still.",
    "vehicle.moving": "The vehicle is moving.",
    "vehicle.parked": "The vehicle is stationary for the whole log.",
    "vehicle.stopped": "The vehicle is stationary now but moves at another time in the log.",
}

# Visibility: the 4 real nuScenes tokens, measured in the output cameras (visibility.py); a database
# written without cameras has nothing to measure it in, and its boxes get UNKNOWN_VISIBILITY.
NUSCENES_VISIBILITY: list[tuple[str, str, str]] = [
    ("1", "v0-40", "visibility of whole object is between 0 and 40%"),
    ("2", "v40-60", "visibility of whole object is between 40 and 60%"),
    ("3", "v60-80", "visibility of whole object is between 60 and 80%"),
    ("4", "v80-100", "visibility of whole object is between 80 and 100%"),
]
UNKNOWN_VISIBILITY = "4"


@dataclass(frozen=True)
class CategoryRule:
    """Where one AV2 category goes: a nuScenes category and, for cycles, whether a rider is on it."""

    nuscenes: str | None  # None: not written (no nuScenes counterpart)
    rider: bool | None = None


# AV2 category -> nuScenes category. None = dropped: nuScenes does not annotate signs.
AV2_TO_NUSCENES: dict[str, CategoryRule] = {
    "ANIMAL": CategoryRule("animal"),
    "ARTICULATED_BUS": CategoryRule("vehicle.bus.bendy"),
    "BICYCLE": CategoryRule("vehicle.bicycle", rider=False),
    "BICYCLIST": CategoryRule("vehicle.bicycle", rider=True),
    "BOLLARD": CategoryRule("movable_object.barrier"),
    "BOX_TRUCK": CategoryRule("vehicle.truck"),
    "BUS": CategoryRule("vehicle.bus.rigid"),
    "CONSTRUCTION_BARREL": CategoryRule("movable_object.trafficcone"),
    "CONSTRUCTION_CONE": CategoryRule("movable_object.trafficcone"),
    "DOG": CategoryRule("animal"),
    "LARGE_VEHICLE": CategoryRule("vehicle.truck"),
    "MESSAGE_BOARD_TRAILER": CategoryRule("vehicle.trailer"),
    "MOBILE_PEDESTRIAN_CROSSING_SIGN": CategoryRule("movable_object.barrier"),
    "MOBILE_PEDESTRIAN_SIGN": CategoryRule("movable_object.barrier"),  # the user guide's spelling
    "MOTORCYCLE": CategoryRule("vehicle.motorcycle", rider=False),
    "MOTORCYCLIST": CategoryRule("vehicle.motorcycle", rider=True),
    "OFFICIAL_SIGNALER": CategoryRule("human.pedestrian.police_officer"),
    "PEDESTRIAN": CategoryRule("human.pedestrian.adult"),
    "RAILED_VEHICLE": CategoryRule("vehicle.bus.rigid"),
    "REGULAR_VEHICLE": CategoryRule("vehicle.car"),
    "SCHOOL_BUS": CategoryRule("vehicle.bus.rigid"),
    "SIGN": CategoryRule(None),
    "STOP_SIGN": CategoryRule(None),
    "STROLLER": CategoryRule("human.pedestrian.stroller"),
    "TRAFFIC_LIGHT_TRAILER": CategoryRule("vehicle.trailer"),
    "TRUCK": CategoryRule("vehicle.truck"),
    "TRUCK_CAB": CategoryRule("vehicle.truck"),
    "VEHICULAR_TRAILER": CategoryRule("vehicle.trailer"),
    "WHEELCHAIR": CategoryRule("human.pedestrian.wheelchair"),
    "WHEELED_DEVICE": CategoryRule("movable_object.pushable_pullable"),
    "WHEELED_RIDER": CategoryRule("human.pedestrian.personal_mobility"),
}

# Speed (m/s, horizontal, over a ~1 s window) above which a box counts as moving. Annotation
# jitter of a parked car is a few cm per frame, i.e. < 0.1 m/s over 1 s.
VEHICLE_MOVING_MPS = 0.5
PEDESTRIAN_MOVING_MPS = 0.3


class UnknownCategoryError(ValueError):
    """A source category has no entry in :data:`AV2_TO_NUSCENES`."""


def category_rule(av2_category: str) -> CategoryRule:
    try:
        return AV2_TO_NUSCENES[av2_category]
    except KeyError:
        known = sorted(AV2_TO_NUSCENES)
        raise UnknownCategoryError(
            f"AV2 category {av2_category!r} has no nuScenes mapping; known: {known}") from None


def attribute_for(av2_category: str, speed_mps: float, track_ever_moves: bool) -> str | None:
    """nuScenes attribute of one box, or None for categories nuScenes gives no attribute.

    Vehicles: moving above :data:`VEHICLE_MOVING_MPS`; otherwise "stopped" if the track moves at
    some time in the log, else "parked". Cycles: rider from the AV2 category. Pedestrians
    (every human.pedestrian.* class): moving or standing; AV2 cannot tell sitting apart.
    """
    rule = category_rule(av2_category)
    name = rule.nuscenes
    if name is None:
        return None
    if rule.rider is not None:
        return "cycle.with_rider" if rule.rider else "cycle.without_rider"
    if name.startswith("vehicle."):
        if speed_mps > VEHICLE_MOVING_MPS:
            return "vehicle.moving"
        return "vehicle.stopped" if track_ever_moves else "vehicle.parked"
    if name.startswith("human.pedestrian."):
        return "pedestrian.moving" if speed_mps > PEDESTRIAN_MOVING_MPS else "pedestrian.standing"
    return None


def moving_threshold(av2_category: str) -> float:
    """Speed above which a track of this category counts as moving (for parked vs stopped)."""
    name = category_rule(av2_category).nuscenes or ""
    return PEDESTRIAN_MOVING_MPS if name.startswith("human.") else VEHICLE_MOVING_MPS
