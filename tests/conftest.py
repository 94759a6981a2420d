"""Shared test setup: tests that compare numbers run on one thread, where torch's reductions
are bit-reproducible (another thread count changes the floating-point order)."""
import numpy as np
import pytest
import torch

torch.set_num_threads(1)


@pytest.fixture
def check_closed_and_unrendered():
    """The contract every environment shares: a closed env refuses step and reset, and
    render() before reset names the mistake."""
    from ncs_lite.envs import make

    def check(closed, env_id: str, **kwargs):
        for call in (lambda: closed.step(np.zeros(6, np.float32)), lambda: closed.reset(seed=0)):
            with pytest.raises(ValueError, match="closed env"):
                call()
        shown = make(env_id, render_mode="rgb_array", **kwargs)
        with pytest.raises(ValueError, match=r"render\(\) before reset"):
            shown.render()
        shown.close()
    return check
