"""Any Gymnasium environment as a task (nmrm_ros.tasks.gym_task): a registered id or a module
path, its facts from its spaces, flattened rewardless states with the env's reward kept aside,
episodes of varying length, and one-line errors for specs that name nothing usable."""

import sys
import textwrap

import numpy as np
import pytest

from nmrm_ros.tasks import check_task, make_env, task_info
from nmrm_ros.tasks.gym_task import TaskSpecError, parse_task_spec


@pytest.fixture
def user_module(tmp_path, monkeypatch):
    """A user's own package, importable, with an env factory and broken ones."""
    (tmp_path / "my_robot_sim.py").write_text(textwrap.dedent('''
        import gymnasium as gym
        import numpy as np

        class Corridor(gym.Env):
            """Walk along a corridor of `length` cells; the episode ends at either end."""
            def __init__(self, length=5):
                self.length = length
                self.observation_space = gym.spaces.Discrete(length)
                self.action_space = gym.spaces.Discrete(2)
            def reset(self, *, seed=None, options=None):
                super().reset(seed=seed)
                self.x = self.length // 2
                return self.x, {}
            def step(self, action):
                self.x += 1 if action == 1 else -1
                done = self.x in (0, self.length - 1)
                self.x = int(np.clip(self.x, 0, self.length - 1))
                return self.x, 7.0, done, False, {}

        def make_env(length=5):
            return Corridor(length)

        def broken(**kwargs):
            raise RuntimeError("the simulator is not running")

        def not_an_env():
            return 42
    '''))
    monkeypatch.syspath_prepend(str(tmp_path))
    yield "my_robot_sim"
    sys.modules.pop("my_robot_sim", None)


def test_a_registered_id_gives_its_facts():
    info = task_info("gym:MountainCar-v0")
    assert (info.state_size, info.discrete, info.action_size, info.episode_length) == (2, True, 3, 200)
    info = task_info("gym:Pendulum-v1,g=9.81")
    assert (info.state_size, info.discrete, info.action_size) == (3, False, 1)
    assert task_info("gym:CartPole-v1,max_steps=50").episode_length == 50


def test_spec_syntax():
    spec = parse_task_spec("gym:LunarLanderContinuous-v3, enable_wind=true, wind_power=5.5, max_steps=300")
    assert spec.kind == "gym" and spec.target == "LunarLanderContinuous-v3"
    assert spec.kwargs == {"enable_wind": True, "wind_power": 5.5} and spec.max_steps == 300
    spec = parse_task_spec("my_robot.sim:make_env,mode=fast")
    assert spec.kind == "import" and spec.target == "my_robot.sim:make_env" and spec.kwargs == {"mode": "fast"}


def test_states_are_flat_floats_and_the_env_reward_is_kept_aside(user_module):
    task = f"{user_module}:make_env,length=7,max_steps=30"
    info = task_info(task)
    assert (info.state_size, info.discrete, info.action_size, info.episode_length) == (7, True, 2, 30)
    env = make_env(task)
    obs, _ = env.reset(seed=0)
    assert obs.dtype == np.float32 and obs.shape == (7,) and obs[3] == 1.0 and obs.sum() == 1.0
    obs, reward, terminated, truncated, info = env.step(1)
    assert reward == 0.0 and info["env_reward"] == 7.0 and obs[4] == 1.0


def test_episodes_vary_in_length():
    env = make_env("gym:CartPole-v1")
    lengths = set()
    for episode in range(8):
        env.reset(seed=episode)
        rng, steps, done = np.random.default_rng(episode), 0, False
        while not done:
            _, _, terminated, truncated, _ = env.step(int(rng.integers(2)))
            steps, done = steps + 1, terminated or truncated
        lengths.add(steps)
    assert len(lengths) > 3 and max(lengths) <= task_info("gym:CartPole-v1").episode_length


@pytest.mark.parametrize("task,message", [
    ("gym:NoSuchEnv-v0", "doesn't exist"),
    ("gym:", "give a Gymnasium id"),
    ("gym:CartPole-v1,oops", "'oops' is not key=value"),
    ("gym:CartPole-v1,max_steps=0", "max_steps must be a positive integer"),
    ("gym:CartPole-v1,nonsense=1", "unexpected keyword argument 'nonsense'"),
    ("gym:Blackjack-v1", "no episode limit; add max_steps=N"),
    ("no_such_module_xyz:make_env", "cannot import 'no_such_module_xyz'"),
    ("{m}:missing", "has no 'missing'"),
    ("{m}:broken", "broken(...) failed: RuntimeError: the simulator is not running"),
    ("{m}:not_an_env", "returned a int, not a gymnasium.Env"),
    ("{m}:Corridor", "no episode limit"),
    ("cartpole", "or your own environment as gym:<id> or <module>:<attribute>"),
])
def test_a_spec_that_names_nothing_usable_is_a_one_line_error(user_module, task, message):
    with pytest.raises(ValueError) as err:
        check_task(task.format(m=user_module))
    assert message in str(err.value) and "\n" not in str(err.value)
    if ":" in task:
        assert isinstance(err.value, TaskSpecError)


def test_the_cli_takes_a_task_spec_and_says_what_is_wrong_in_one_line():
    import subprocess

    from nmrm_ros.testing.graph import executable

    res = subprocess.run([executable("nmrm"), "dataset", "screen", "--task", "gym:NoSuchEnv-v0"],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and "gym:NoSuchEnv-v0" in res.stderr and "Traceback" not in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1, res.stderr


def test_xy_names_the_dimensions_the_page_draws_as_a_path():
    from nmrm_ros.tasks.arena import arena as _arena

    assert parse_task_spec("gym:MountainCar-v0,xy=0/1").xy == (0, 1)
    assert _arena("gym:MountainCar-v0,xy=0/1") == {"bounds": None, "zones": [], "xy": [0, 1]}
    assert _arena("gym:MountainCar-v0") is None
    for bad in ("xy=0", "xy=a/b", "xy=1/1", "xy=-1/0"):
        with pytest.raises(TaskSpecError, match="xy must name two state dimensions"):
            parse_task_spec(f"gym:MountainCar-v0,{bad}")
    with pytest.raises(TaskSpecError, match="the state has 2 dimensions"):
        task_info("gym:MountainCar-v0,xy=0/5")
