"""A failed PX4 take-off's story compares how the height moved with the climb PX4 reported."""

from __future__ import annotations

from avoidd.mavlink import codec as mav
from avoidd.sim.px4 import climb_story

CODEC = mav.Codec(1, 1)


def _position(t_ms: int, height_m: float, climb_m_s: float) -> mav.Message:
    # GLOBAL_POSITION_INT: relative_alt in mm, vz in cm/s down.
    return CODEC.decode(
        CODEC.pack(
            CODEC.build(
                "GLOBAL_POSITION_INT",
                t_ms,
                0,
                0,
                0,
                round(height_m * 1000),
                0,
                0,
                round(-climb_m_s * 100),
                0,
            )
        )
    )[0]


def test_a_stalled_climb_shows_the_reported_rate_beside_the_heights() -> None:
    # Ten seconds at 4 Hz: the height stays at 0.8 m while PX4 says it climbs at 0.4 m/s.
    stalled = [_position(1000 + 250 * i, 0.8, 0.4) for i in range(41)]
    assert climb_story(stalled) == "; last 5 s: height +0.00 m/s, reported climb +0.40 m/s"


def test_a_real_climb_agrees_and_only_the_last_window_counts() -> None:
    # Still on the ground for 10 s, then 5 s climbing at 0.5 m/s as reported.
    ground = [_position(250 * i, 0.0, 0.0) for i in range(40)]
    climbing = [_position(10_000 + 250 * i, 0.125 * i, 0.5) for i in range(21)]
    assert climb_story(ground + climbing) == (
        "; last 5 s: height +0.50 m/s, reported climb +0.50 m/s"
    )


def test_too_little_to_tell_says_nothing() -> None:
    assert climb_story([]) == ""
    assert climb_story([_position(1000, 0.5, 0.1)]) == ""
    assert climb_story([_position(1000, 0.5, 0.1), _position(1500, 0.6, 0.1)]) == ""
