"""platkit.kinematics.platform_model: one kinematic model per spec object and thread, the helper
effects take rather than building a PlatformModel per call."""
import copy
import threading

from platkit.kinematics import PlatformModel, platform_model
from platkit.plugins import get_platform


def test_one_model_per_spec_object_and_thread():
    spec = get_platform("rotary")
    model = platform_model(spec)
    assert isinstance(model, PlatformModel) and model.spec is spec
    assert platform_model(spec) is model
    other = copy.copy(spec)  # another spec object of the same stand: a model of its own
    assert platform_model(other) is not model and platform_model(other).spec is other
    assert platform_model(spec) is model
    seen = []
    thread = threading.Thread(target=lambda: seen.append(platform_model(spec)))
    thread.start()
    thread.join()
    assert seen[0] is not model and seen[0].spec is spec
