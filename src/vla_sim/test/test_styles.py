"""The catalogue admits exactly the looks the scene draws (a catalogue refuses any other style)."""
from vla_common import catalogue
from vla_sim import scene


def test_the_scene_draws_every_style_the_catalogue_admits():
    assert set(scene.STYLES) == set(catalogue.STYLES)
