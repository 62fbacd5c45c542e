"""The designed excitation: its spectrum lies in the band, its peak at the limit, and babbling uses it."""

import numpy as np
import pytest

from softpend.plant import RodParams
from softpend.sysid.babble import BabbleProtocol, babble, multisine, multisine_frequencies_hz


def test_multisine_power_lies_in_its_band_with_equal_lines_and_its_peak_is_the_limit():
    dt_s, period_s, band = 0.01, 5.0, (0.2, 6.0)
    u = multisine(int(period_s / dt_s) * 4, dt_s, 0.05, band, period_s)
    assert np.max(np.abs(u)) == pytest.approx(0.05, rel=1e-12)
    spectrum = np.abs(np.fft.rfft(u)) ** 2
    f = np.fft.rfftfreq(u.size, dt_s)
    inside = (f >= band[0] - 1e-9) & (f <= band[1] + 1e-9)
    assert spectrum[inside].sum() / spectrum.sum() > 0.999999
    lines = spectrum[np.isin(np.round(f, 6), np.round(multisine_frequencies_hz(period_s, band), 6))]
    assert lines.size == 30 and lines.max() / lines.min() < 1 + 1e-6  # a flat line spectrum
    # Schroeder phases keep the crest factor well below a random-phase multisine's (about 3 to 4)
    assert np.max(np.abs(u)) / np.sqrt(np.mean(u**2)) < 2.5


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(band_hz=(0.0, 5.0)), "band_hz"),
        (dict(band_hz=(3.0, 2.0)), "band_hz"),
        (dict(band_hz=(0.2, 60.0)), "Nyquist"),
        (dict(band_hz=(0.21, 0.39)), "no harmonic"),
        (dict(period_s=0.0), "period_s"),
    ],
)
def test_multisine_refuses_bad_settings_by_name(kwargs, message):
    with pytest.raises(ValueError, match=message):
        multisine(100, 0.01, 0.05, **kwargs)


def test_multisine_babbling_drives_the_rod_with_the_program_within_the_torque_limit():
    limit = RodParams().torque_limit_nm
    protocol = BabbleProtocol(
        n_trials=1, trial_length_s=2.0, start="hanging", feedback_trial_fraction=0.0, program="multisine"
    )
    data = babble(protocol, seed=3, progress=False)
    expected = multisine(protocol.n_samples, protocol.dt_s, 0.8 * limit, (0.2, protocol.torque_bandwidth_hz))
    # the stored samples start one step in (the first backward difference needs a sample before them)
    np.testing.assert_allclose(data.torques_nm[0], expected[1 : 1 + data.torques_nm.shape[1]])
    assert np.max(np.abs(data.torques_nm)) <= limit
    with pytest.raises(ValueError, match="program"):
        BabbleProtocol(program="chirp")
