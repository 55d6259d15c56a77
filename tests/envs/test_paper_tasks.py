"""The SGFD paper's own tasks as its authors' code built them, the ids' defaults: HiP-BMDP's robot files for the MT
ids (the authors' splits, their frame lag one keyword away), still images under the authors' colour key for the
background ids; and the family a run recorded before version 0.3.0 trained on.

The references are built here from the published facts (mtenv's ``local_dm_control_suite``, the SGFD authors'
``dmc2gym/wrappers.py``) by editing dm_control's own XML text, a different path from the package's (which edits
parsed trees), and rendered by dm_control's ``physics.render``.
"""

# First: importing sgfd_envs picks MuJoCo's headless OpenGL backend, which must precede dm_control.
import sgfd_envs

# isort: split

import warnings

import cv2
import gymnasium as gym
import numpy as np
import pytest
from dm_control.mujoco import Physics
from dm_control.suite import common
from stable_baselines3.common.vec_env import DummyVecEnv

from bench.benchmark_methods import interior
from sgfd_envs.builders import MorphologyWarning, StandInWarning
from sgfd_envs.families import EARLIER_FAMILY, env_kwargs_as_trained, family_kwargs
from sgfd_envs.state import ResumableState

SIZE = 84
MT_ID = {"walker": "SGFD/MT-walker-walk-v0", "cheetah": "SGFD/MT-cheetah-run-v0", "finger": "SGFD/MT-finger-spin-v0"}
DM_FLOOR = 'rgb1=".1 .2 .3" rgb2=".2 .3 .4" width="300" height="300" mark="edge" markrgb=".2 .3 .4"'
# The local materials files' floors (mtenv's common/materials.xml and materials_white_floor.xml).
BLUE_FLOOR = 'rgb1=".1 .1 .4" rgb2=".2 .2 .8" width="300" height="300" mark="edge" markrgb=".1 .1 .4"'
GREY_FLOOR = 'rgb1=".1 .1 .1" rgb2=".2 .2 .2" width="300" height="300" mark="edge" markrgb=".1 .1 .1"'


def replaced(text: str, old: str, new: str) -> str:
    assert text.count(old) == 1, old
    return text.replace(old, new)


def reference_assets() -> dict[str, bytes]:
    materials = common.ASSETS["./common/materials.xml"].decode()
    blue = replaced(materials, DM_FLOOR, BLUE_FLOOR)
    blue = replaced(blue, 'name="decoration" rgba=".3 .5 .7 1"', 'name="decoration" rgba=".7 .5 .3 1"')
    sky = replaced(common.ASSETS["./common/skybox.xml"].decode(), 'markrgb="1 1 1"', 'markrgb="0 0 0"')
    return {
        "./common/visual.xml": common.ASSETS["./common/visual.xml"],
        "./common/skybox.xml": sky.encode(),
        "./common/materials.xml": blue.encode(),
        "./common/materials_white_floor.xml": replaced(materials, DM_FLOOR, GREY_FLOOR).encode(),
    }


def reference_xml(robot: str, n: int) -> str:
    """HiP-BMDP's file n of a robot, from the table of facts."""
    xml = common.read_model(f"{robot}.xml").decode()
    if robot == "finger":
        return replaced(xml, 'size=".025 .03 .025"', f'size="{0.025 * n:.3f} .03 .025"')
    xml = replaced(xml, '"./common/materials.xml"', '"./common/materials_white_floor.xml"')
    if robot == "walker":
        foot = 'name="left_foot" zaxis="1 0 0" size="0.05 '
        return replaced(xml, f'{foot}0.1"', f'{foot}{0.07 + 0.01 * n:.2f}"')
    half = f"{0.4 + 0.1 * n:.1f}"
    return replaced(xml, 'fromto="-.5 0 0 .5 0 0"', f'fromto="-{half} 0 0 {half} 0 0"')


def reference_physics(robot: str, n: int) -> Physics:
    return Physics.from_xml_string(reference_xml(robot, n), reference_assets())


def model_fields(physics: Physics) -> dict[str, np.ndarray]:
    model = physics.model.ptr
    fields = {name: getattr(model, name) for name in dir(model) if not name.startswith("_")}
    return {
        name: value for name, value in fields.items() if isinstance(value, np.ndarray) and value.dtype.kind in "fiu"
    }


def render_at(reference: Physics, physics: Physics) -> np.ndarray:
    """dm_control's render of ``reference`` in the state (and the task's per-episode model colours and damping) of
    ``physics``."""
    for name in ("site_rgba", "dof_damping"):  # what dm_control's finger tasks set at each reset
        getattr(reference.model, name)[:] = getattr(physics.model, name)
    reference.set_state(physics.get_state())
    reference.forward()
    return reference.render(SIZE, SIZE, camera_id=0)


# --- HiP-BMDP's robots ------------------------------------------------------------------------------


@pytest.mark.parametrize("robot", ["walker", "cheetah", "finger"])
def test_every_setting_compiles_to_the_model_of_hipbmdps_file(robot):
    for setting in range(1, 11):
        with gym.make(MT_ID[robot], setting=setting, obs_type="state") as env:
            ours = model_fields(env.unwrapped.physics)
        reference = model_fields(reference_physics(robot, setting))
        assert ours.keys() == reference.keys() and len(ours) > 100
        for name, value in reference.items():
            np.testing.assert_array_equal(ours[name], value, err_msg=f"{robot} {setting} {name}")


@pytest.mark.parametrize(("robot", "setting"), [("walker", 10), ("cheetah", 10), ("finger", 1)])
def test_pixels_are_dm_controls_render_of_the_file_at_the_same_state(robot, setting):
    reference = reference_physics(robot, setting)
    with gym.make(MT_ID[robot], setting=setting) as env:
        observation, _ = env.reset(seed=0)
        np.testing.assert_array_equal(observation, render_at(reference, env.unwrapped.physics))
        for _ in range(3):
            observation, *_ = env.step(env.action_space.sample())
        np.testing.assert_array_equal(observation, render_at(reference, env.unwrapped.physics))


def test_the_authors_splits_are_the_default_and_the_scaled_robots_keep_their_own():
    expected = {"train": [2, 3, 5, 6], "interpolation": [4], "extrapolation": [10]}
    scaled = {"train": [1, 2, 4, 5], "interpolation": [3], "extrapolation": [10]}
    for robots, table in ((None, expected), ("scaled", scaled)):
        kwargs = {} if robots is None else {"robots": robots}
        for split, settings in table.items():
            venv = sgfd_envs.make_domain_vec_env("SGFD/MT-cheetah-run-v0", split, obs_type="state", **kwargs)
            try:
                assert venv.get_attr("setting") == settings
            finally:
                venv.close()
    with gym.make("SGFD/MT-walker-run-v0", split="interpolation", obs_type="state") as env:
        assert env.unwrapped.morphology_parameter == "left_foot_half_length"
        assert env.unwrapped.morphology_value == pytest.approx(0.11)
    with gym.make("SGFD/MT-cheetah-run-v0", split="extrapolation", obs_type="state") as env:
        assert env.unwrapped.morphology_value == pytest.approx(2.8)  # the torso from -1.4 to 1.4 m


def test_hipbmdps_finger_files_change_no_pixel_and_no_motion_and_the_ids_say_so():
    trajectories, said = [], []
    for setting in (1, 9):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            env = gym.make("SGFD/MT-finger-turn-v0", setting=setting)
        said += [str(warning.message) for warning in caught if issubclass(warning.category, MorphologyWarning)]
        frames, positions = [env.reset(seed=2)[0]], []
        rng = np.random.default_rng(0)
        for _ in range(60):
            frames.append(env.step(rng.uniform(-1, 1, 2).astype(np.float32))[0])
            positions.append(env.unwrapped.physics.data.qpos.copy())
        env.close()
        trajectories.append((np.stack(frames), np.stack(positions)))
    (frames_1, qpos_1), (frames_9, qpos_9) = trajectories
    np.testing.assert_array_equal(frames_1, frames_9)
    np.testing.assert_array_equal(qpos_1, qpos_9)
    # said once per process (an earlier test in this process may have made a finger id already)
    assert len(said) <= 1
    for message in said:
        assert "invisible touch-sensor sites" in message and "robots='scaled'" in message


# --- the authors' frame lag ---------------------------------------------------------------------------


def test_frame_lag_gives_the_observation_of_two_agent_steps_earlier_and_resumes():
    actions = np.random.default_rng(1).uniform(-1, 1, (8, 6)).astype(np.float32)

    def run(**kwargs):
        with gym.make("SGFD/MT-walker-walk-v0", obs_type="state", **kwargs) as env:
            first, _ = env.reset(seed=4)
            steps = [env.step(action) for action in actions]
        return [first, *(step[0] for step in steps)], [step[1] for step in steps]

    plain, plain_rewards = run()
    lagged, lagged_rewards = run(frame_lag=True)
    assert plain_rewards == lagged_rewards  # the rewards are the current step's
    for t, observation in enumerate(lagged):
        np.testing.assert_array_equal(observation, plain[max(t - 2, 0)])
    # the lag's history is part of the state a resumed run continues from
    env = ResumableState(gym.make("SGFD/MT-walker-walk-v0", obs_type="state", frame_lag=True))
    env.reset(seed=4)
    for action in actions[:5]:
        env.step(action)
    state = env.get_training_state()
    continued = [env.step(action)[0] for action in actions[5:]]
    env.set_training_state(state)
    np.testing.assert_array_equal(np.stack([env.step(action)[0] for action in actions[5:]]), np.stack(continued))
    env.close()


# --- the paper's still images under the authors' colour key -----------------------------------------


def keyed(render: np.ndarray, image: np.ndarray) -> np.ndarray:
    """The authors' ``_get_obs``: the pixels whose blue exceeds red and green take the image's."""
    mask = (render[..., 2] > render[..., 1]) & (render[..., 2] > render[..., 0])
    frame = render.copy()
    frame[mask] = image[mask]
    return frame


@pytest.fixture(scope="module")
def five_images(tmp_path_factory):
    folder = tmp_path_factory.mktemp("images")
    rng = np.random.default_rng(0)
    for i in range(1, 6):
        image = rng.integers(0, 256, (60 + 7 * i, 90, 3), dtype=np.uint8)
        image[:, : 10 * i] = (255, 0, 0)  # blue in OpenCV's order: a band that shows which order is pasted
        assert cv2.imwrite(str(folder / f"{i}.png"), image)
    return folder


def test_a_folder_of_five_images_is_the_authors_setup_pasted_in_bgr(five_images):
    assert sgfd_envs.n_domains("SGFD/walker-walk-v0", "train", background_dir=five_images) == 4
    assert sgfd_envs.n_domains("SGFD/walker-walk-v0", "test", background_dir=five_images) == 1
    reference = reference_physics("walker", 3)  # the local unmodified walker (walker.xml = walker_len_3)
    for split, domain, name in (("train", 2, "3.png"), ("test", 0, "5.png")):
        image = cv2.resize(cv2.imread(str(five_images / name)), (SIZE, SIZE))  # BGR, resized as the authors do
        with gym.make("SGFD/walker-walk-v0", split=split, domain=domain, background_dir=five_images) as env:
            observations = [env.reset(seed=0)[0]]
            expected = [keyed(render_at(reference, env.unwrapped.physics), image)]
            for _ in range(3):
                observations.append(env.step(env.action_space.sample())[0])
                expected.append(keyed(render_at(reference, env.unwrapped.physics), image))
        np.testing.assert_array_equal(np.stack(observations), np.stack(expected))
    # the sky goes under the key, the walker's grey floor does not
    sky_and_floor = reference.render(SIZE, SIZE, camera_id=0, segmentation=True)[..., 0]
    sky = interior(sky_and_floor == -1)
    floor = interior(sky_and_floor == reference.model.name2id("floor", "geom"))
    changed = np.any(observations[-1] != reference.render(SIZE, SIZE, camera_id=0), axis=-1)
    assert changed[sky].mean() > 0.9 and not changed[floor].any()


def test_the_built_in_stand_in_is_five_still_images_flagged():
    images = {}
    for split, count in (("train", 4), ("test", 1)):
        assert sgfd_envs.n_domains("SGFD/finger-spin-v0", split) == count
        assert sgfd_envs.stand_in("SGFD/finger-spin-v0", split).startswith("procedural still images")
        for domain in range(count):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", StandInWarning)
                env = gym.make("SGFD/finger-spin-v0", split=split, domain=domain, image_size=48)
            observations, info = [env.reset(seed=0)[0]], env.reset(seed=0)[1]
            renders = [env.unwrapped.physics.render(48, 48, camera_id=0)]
            for _ in range(4):
                observations.append(env.step(np.ones(2, dtype=np.float32))[0])
                renders.append(env.unwrapped.physics.render(48, 48, camera_id=0))
            env.close()
            assert info["stand_in"]
            # every keyed pixel of every step shows the same image: a still one
            image = np.zeros((48, 48, 3), dtype=int) - 1
            for observation, render in zip(observations, renders, strict=True):
                mask = (render[..., 2] > render[..., 0]) & (render[..., 2] > render[..., 1])
                np.testing.assert_array_equal(observation[~mask], render[~mask])
                seen = mask & (image[..., 0] >= 0)
                np.testing.assert_array_equal(observation[seen], image[seen])
                image[mask] = observation[mask]
            images[split, domain] = image
    assert len({image.tobytes() for image in images.values()}) == 5


def test_a_video_is_refused_as_a_still_image_naming_the_keyword(tmp_path, five_images):
    for i in range(5):
        (tmp_path / f"{i}.mp4").write_bytes((five_images / f"{i + 1}.png").read_bytes())
    with pytest.raises(ValueError, match=r"is a video, and backgrounds='still' shows one image per domain: .*'moving'"):
        gym.make("SGFD/walker-walk-v0", background_dir=tmp_path)
    with pytest.raises(ValueError, match=r"test_domains must be None with background_dir \(its files decide\), got 4"):
        gym.make("SGFD/walker-walk-v0", background_dir=five_images, test_domains=4)


def test_the_earlier_backgrounds_are_one_keyword_each_away(five_images):
    with gym.make("SGFD/cheetah-run-v0", backgrounds="moving", image_size=48) as env:
        env.reset(seed=0)
        frames = [env.step(np.zeros(6, dtype=np.float32))[0] for _ in range(2)]
    assert not np.array_equal(*frames)  # a moving texture
    assert sgfd_envs.n_domains("SGFD/cheetah-run-v0", "test", test_domains=4) == 4
    image = cv2.resize(cv2.imread(str(five_images / "1.png")), (SIZE, SIZE))
    reference = reference_physics("walker", 3)
    with gym.make("SGFD/walker-walk-v0", background_dir=five_images, background_channels="rgb") as env:
        observation, _ = env.reset(seed=0)
        np.testing.assert_array_equal(observation, keyed(render_at(reference, env.unwrapped.physics), image[..., ::-1]))
    with gym.make("SGFD/walker-walk-v0", robots="dm_control", obs_type="state") as env:
        assert not np.array_equal(env.unwrapped.physics.model.tex_data, reference.model.tex_data)


# --- what a run recorded decides its family -----------------------------------------------------------


def test_a_run_that_recorded_no_family_gets_the_earlier_one():
    assert family_kwargs("SGFD/MT-walker-walk-v0", {"obs_type": "state"}) == {"robots": "hipbmdp"}
    assert family_kwargs("SGFD/walker-walk-v0")["compositing"] == "colour_key"
    assert family_kwargs("DMCGB/walker-walk-v0") == {}
    earlier = env_kwargs_as_trained("SGFD/MT-walker-walk-v0", {"obs_type": "state"}, None)
    assert earlier == {"obs_type": "state", "robots": "scaled"}
    assert env_kwargs_as_trained("SGFD/walker-walk-v0", {}, None) == EARLIER_FAMILY["background"]
    with_folder = env_kwargs_as_trained("SGFD/walker-walk-v0", {"background_dir": "clips"}, None)
    assert "test_domains" not in with_folder and with_folder["backgrounds"] == "moving"
    recorded = env_kwargs_as_trained("SGFD/MT-walker-walk-v0", {"obs_type": "state"}, {"robots": "hipbmdp"})
    assert recorded == {"obs_type": "state", "robots": "hipbmdp"}
    venv = sgfd_envs.make_domain_vec_env("SGFD/MT-walker-walk-v0", **earlier)
    try:
        assert isinstance(venv, DummyVecEnv) and venv.get_attr("setting") == [1, 2, 4, 5]
    finally:
        venv.close()
