import jax

import jaxanom


def test_version_is_a_string():
    assert isinstance(jaxanom.__version__, str) and jaxanom.__version__


def test_four_simulated_devices():
    assert jax.device_count() == 4
