"""Readers of a run never touch it; damaged checkpoints are checkpoint errors."""
import numpy as np
import pytest

import jax.numpy as jnp

from compiles import compiled_during
from jaxanom.train.checkpoint import Checkpointer, restore_checkpoint


def _tree(root):
    return sorted((str(p.relative_to(root)), p.stat().st_mtime_ns) for p in root.rglob("*"))


def _saved(tmp_path, weights):
    folder = tmp_path / "checkpoints"
    with Checkpointer(folder, save_every=1) as checkpointer:
        checkpointer.save(1, {"w": weights}, {"index": 1})
    return folder


def test_reading_a_live_run_leaves_its_unfinished_save_alone(tmp_path):
    folder = _saved(tmp_path, jnp.arange(6.0))
    unfinished = folder / "2.orbax-checkpoint-tmp"  # a writer's save in progress
    unfinished.mkdir()
    (unfinished / "part").write_bytes(b"in progress")
    before = _tree(tmp_path)
    state, data = restore_checkpoint(folder, {"w": jnp.zeros(6)})
    np.testing.assert_array_equal(state["w"], np.arange(6.0))
    assert data == {"index": 1}
    assert unfinished.is_dir() and _tree(tmp_path) == before  # nothing created, removed or touched


def test_a_reader_creates_no_folder(tmp_path):
    folder = _saved(tmp_path, jnp.arange(3.0))
    with Checkpointer(tmp_path / "elsewhere", read_only=True) as reader:
        assert reader.latest_step() is None
    assert not (tmp_path / "elsewhere").exists()
    with Checkpointer(folder, read_only=True) as reader:
        assert reader.latest_step() == 1


@pytest.mark.parametrize("where", ["host", "accelerator"])  # read by NumPy / by one compiled reduction
def test_nan_in_restored_parameters_is_a_checkpoint_error(tmp_path, monkeypatch, where):
    import jaxanom.train.checkpoint as checkpoint

    if where == "accelerator":  # the path of arrays restored onto a GPU, taken here on the CPU
        monkeypatch.setattr(checkpoint, "in_host_memory", lambda x: False)
    folder = _saved(tmp_path, {"a": jnp.ones(2), "w": jnp.array([1.0, jnp.nan, 3.0]), "z": jnp.zeros(4)})
    with pytest.raises(ValueError, match=r"step 1 holds NaN/Inf in 1 array\(s\).*\['w'\]\['w'\].*delete that step"):
        restore_checkpoint(folder, {"w": {"a": jnp.ones(2), "w": jnp.zeros(3), "z": jnp.zeros(4)}})


def test_truncated_checkpoint_data_is_a_one_line_checkpoint_error(tmp_path):
    folder = _saved(tmp_path, jnp.arange(5000.0))
    data = max((p for p in (folder / "1").rglob("*") if p.is_file()), key=lambda p: p.stat().st_size)
    data.write_bytes(data.read_bytes()[: data.stat().st_size // 2])  # TensorStore's error spans ~60 lines
    with pytest.raises(ValueError, match="step 1 cannot be read") as error:
        restore_checkpoint(folder, {"w": jnp.zeros(5000)})
    assert len(str(error.value).splitlines()) == 1 and "delete that step" in str(error.value)


def test_a_replicated_state_saves_and_restores_without_a_compile_per_array_and_device(tmp_path):
    """orbax's replica-parallel writes sliced each small replicated array per device (one compile
    per shape and device: 216 in the MMF quick demo) and the NaN check compiled per leaf."""
    import jax

    from jaxanom.train.sharding import make_mesh, replicated

    state = jax.device_put({f"w{i}": jnp.full((3, i + 1), float(i)) for i in range(6)}, replicated(make_mesh(jax.devices())))
    def save():
        with Checkpointer(tmp_path, save_every=1) as checkpointer:
            checkpointer.save(1, state)

    _, on_save = compiled_during(save)
    (restored, _), on_restore = compiled_during(lambda: restore_checkpoint(tmp_path, state))
    assert on_save == [] and len(on_restore) <= 1, (on_save, on_restore)
    for key, value in state.items():
        assert restored[key].sharding == value.sharding
        np.testing.assert_array_equal(restored[key], value)
