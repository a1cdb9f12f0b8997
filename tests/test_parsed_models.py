"""Envs built from a model parsed once per file: each env's own copy, equal to a fresh parse, whatever other envs
did to theirs; the cache bounded; MuJoCo's own parser back in place afterwards, also with threads building envs."""

from concurrent.futures import ThreadPoolExecutor

import mujoco
import numpy as np

from adademo_lerobot.suites import parsed_models
from adademo_lerobot.suites.gym_robotics import make_raw_env as make_adroit_env
from adademo_lerobot.suites.metaworld import MT10, make_raw_env

STOCK_PARSE = mujoco.MjModel.from_xml_path


def _arrays(model: mujoco.MjModel) -> dict[str, np.ndarray]:
    return {
        name: value.copy()
        for name in dir(model)
        if not name.startswith("_") and isinstance(value := getattr(model, name), np.ndarray)
    }


def _assert_same_model(model: mujoco.MjModel, expected: mujoco.MjModel) -> None:
    got, want = _arrays(model), _arrays(expected)
    assert got.keys() == want.keys() and len(got) > 100
    for name in want:
        np.testing.assert_array_equal(got[name], want[name], err_msg=name)


def test_an_env_gets_a_pristine_copy_whatever_an_earlier_env_did_to_its_model():
    first = make_raw_env("door-open-v3")
    first.seeded_rand_vec, first._freeze_rand_vec = True, False
    for seed in range(3):  # door-open's reset moves the door body in the model
        first.seed(seed)
        first.reset()
    first.model.body_pos[:] += 1.0
    first.model.geom_size[:] *= 2.0
    second = make_raw_env("door-open-v3")
    assert second.model is not first.model
    assert parsed_models._parsed[second.fullpath] is not second.model  # the parsed model is never handed out
    parsed_models._parsed.clear()
    expected = make_raw_env("door-open-v3")  # from a fresh parse
    _assert_same_model(second.model, expected.model)
    assert mujoco.MjModel.from_xml_path is STOCK_PARSE or mujoco.MjModel.from_xml_path == STOCK_PARSE


def test_a_copy_steps_as_a_freshly_parsed_model():
    env = make_adroit_env("AdroitHandDoor-v1")
    fresh = STOCK_PARSE(env.fullpath)
    data, fresh_data = env.data, mujoco.MjData(fresh)
    rng = np.random.default_rng(0)
    for _ in range(50):
        data.ctrl[:] = fresh_data.ctrl[:] = rng.uniform(-1, 1, fresh.nu)
        mujoco.mj_step(env.model, data)
        mujoco.mj_step(fresh, fresh_data)
    np.testing.assert_array_equal(data.qpos, fresh_data.qpos)
    np.testing.assert_array_equal(data.qvel, fresh_data.qvel)


def test_the_cache_keeps_the_models_of_the_most_recently_used_files_only():
    parsed_models._parsed.clear()
    used, template = [], None  # files in order of last use; MT10's last task's parsed model
    for task in [*MT10, "hammer-v3", "bin-picking-v3", "basketball-v3", "assembly-v3", MT10[-1]]:
        env = make_raw_env(task)
        used = [f for f in used if f != env.fullpath] + [env.fullpath]
        if task == MT10[-1] and template is None:
            template = parsed_models._parsed[env.fullpath]
    assert len(used) > parsed_models.KEPT_MODELS  # (some tasks share a file)
    assert list(parsed_models._parsed) == used[-parsed_models.KEPT_MODELS :]
    assert parsed_models._parsed[used[-1]] is template  # a file used again is not parsed again


def test_threads_building_envs_leave_mujocos_own_parser_in_place():
    with ThreadPoolExecutor(4) as pool:
        envs = list(pool.map(make_raw_env, ["reach-v3", "push-v3", "window-open-v3", "drawer-close-v3"] * 3))
    assert len({id(env.model) for env in envs}) == len(envs)
    assert mujoco.MjModel.from_xml_path == STOCK_PARSE
