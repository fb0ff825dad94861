"""Test set-up: 4 simulated CPU devices, configured before JAX starts a backend."""
import jax

jax.config.update("jax_num_cpu_devices", 4)
jax.config.update("jax_platforms", "cpu")
