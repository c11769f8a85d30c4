"""Bad descriptions give a clear error that names the field."""
import pytest

from gausstac_maniskill.config import Material, SolverSettings
from gausstac_maniskill.errors import ConfigError


@pytest.mark.parametrize("E", [0.0, -1e5, float("nan"), float("inf")])
def test_young_modulus_must_be_positive_finite(E):
    with pytest.raises(ConfigError, match=r"Material\.E"):
        Material(E=E)


@pytest.mark.parametrize("nu", [0.5, 0.6, -1.0])
def test_poisson_ratio_below_one_half(nu):
    with pytest.raises(ConfigError, match=r"Material\.nu"):
        Material(nu=nu)


def test_other_material_fields():
    with pytest.raises(ConfigError, match=r"Material\.density"):
        Material(density=0)
    with pytest.raises(ConfigError, match=r"Material\.model"):
        Material(model="jelly")
    with pytest.raises(ConfigError, match=r"Material\.yield_compression"):
        Material(model="foam", yield_compression=1.5)


def test_lame_parameters_and_wave_speed():
    m = Material(E=3e5, nu=0.45, density=1100)
    assert m.mu == pytest.approx(3e5 / 2.9)
    assert m.lam == pytest.approx(3e5 * 0.45 / (1.45 * 0.1))
    assert m.wave_speed == pytest.approx(((m.lam + 2 * m.mu) / 1100) ** 0.5)


@pytest.mark.parametrize("field,value", [("dx", 0), ("cfl", 1.5), ("max_substeps", 0),
                                         ("mass_scaling", 0.5), ("damping", -1.0),
                                         ("gravity", (0, 1)), ("particles_per_axis", 7),
                                         ("hold_scaling", 0.5), ("hold_speed", 0.0)])
def test_solver_settings_fields(field, value):
    with pytest.raises(ConfigError, match=rf"SolverSettings\.{field}"):
        SolverSettings(**{field: value})


def test_padspec_along_is_orthogonalised_and_checked():
    from gausstac_maniskill.config import PadSpec
    from gausstac_maniskill.errors import ConfigError

    p = PadSpec(link="l", axis=(1.0, 0.0, 0.0), along=(1.0, 1.0, 0.0))
    assert p.along == pytest.approx((0.0, 1.0, 0.0))
    with pytest.raises(ConfigError, match="parallel"):
        PadSpec(link="l", axis=(1.0, 0.0, 0.0), along=(2.0, 0.0, 0.0))
