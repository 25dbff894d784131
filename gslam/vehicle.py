"""Vehicle presets for the Ackermann (car-like) motion model of the paper (eq. kinem)."""

from __future__ import annotations

from dataclasses import asdict, dataclass


@dataclass(frozen=True)
class AckermannVehicle:
    """Geometry of the Sydney ute.

    wheelbase_m (L): distance between the axles; encoder_offset_m (H): rear-axle centre to the
    rear-left wheel whose speed is measured; laser_x_m, laser_y_m (a, b): laser position in the car
    frame (x ahead of the rear axle, y to the left).
    """

    name: str
    wheelbase_m: float
    encoder_offset_m: float
    laser_x_m: float
    laser_y_m: float

    def as_dict(self) -> dict[str, float | str]:
        return asdict(self)


VEHICLE_PRESETS: dict[str, AckermannVehicle] = {
    # ACFR's own code for the Car Park and Victoria Park data.
    "carpark": AckermannVehicle("carpark", 2.83, 0.76, 3.78, 0.50),
    # The values the paper quotes: L = 2.75, H = 0.74, a = L + 0.5, b = 0.5.
    "paper": AckermannVehicle("paper", 2.75, 0.74, 2.75 + 0.5, 0.50),
}


def vehicle_preset(name: str) -> AckermannVehicle:
    try:
        return VEHICLE_PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown vehicle preset {name!r}; choose one of {', '.join(VEHICLE_PRESETS)}") from None
