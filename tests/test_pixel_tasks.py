"""Image states (issue 53): the pixel navigation tasks, their datasets, and reward models with an
image encoder in every architecture (batched, per member and online alike; trained, saved, served)."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
import torch

from nmrm_ros.datasets.screening import generate_screened
from nmrm_ros.datasets.trajectories import TrajectoryDataset, concatenate
from nmrm_ros.mil import ARCHITECTURES, OnlineRewardModel, fit, load_checkpoint, load_train_config, model_config
from nmrm_ros.mil.data import BagTensors, normalisation
from nmrm_ros.mil.ensemble import init_ensemble
from nmrm_ros.mil.models import ModelConfig, build_model
from nmrm_ros.tasks import PIXEL_TASKS, make_env, task_info
from nmrm_ros.tasks.navigation import NavigationEnv
from nmrm_ros.tasks.pixel_navigation import IMAGE_SIZE, pixel_dataset, render_positions


@pytest.fixture(scope="module")
def key_data():
    """60 screened Key episodes and their pixel version."""
    ds = generate_screened("key", 60, seed=5)
    return ds, pixel_dataset(ds, "key_pixels")


def test_pixel_task_info_and_env():
    for task in PIXEL_TASKS:
        info = task_info(task)
        assert info.image_shape == (IMAGE_SIZE, IMAGE_SIZE, 3) and info.state_size == info.image_values == 3072
        assert info.privileged_size == 2 and info.pixels_of == task.removesuffix("_pixels")
        assert info.family == "navigation" and not info.navigation
    env, plain = make_env("key_pixels"), NavigationEnv("key")
    obs, info = env.reset(seed=3)
    position, _ = plain.reset(seed=3)
    assert obs.shape == (3072,) and env.observation_space.contains(obs)
    np.testing.assert_array_equal(info["privileged"], position)  # the same simulator, the same draws
    obs, _, _, _, info = env.step(4)
    np.testing.assert_array_equal(info["privileged"], plain.step(4)[0])
    with pytest.raises(ValueError, match="discrete actions only"):
        make_env("key_pixels", continuous=True)


def test_the_image_shows_the_agent_where_it_is():
    positions = np.array([[0.1, 0.1], [0.5, 0.9], [0.93, 0.47]])
    images = render_positions("key", positions)
    assert images.shape == (3, IMAGE_SIZE, IMAGE_SIZE, 3) and images.dtype == np.uint8
    for image, (x, y) in zip(images, positions):
        row, col = np.unravel_index(np.argmax(image[..., 0].astype(int) - image[..., 1]), image.shape[:2])
        assert abs(col + 0.5 - x * IMAGE_SIZE) <= 1.0 and abs(row + 0.5 - (1 - y) * IMAGE_SIZE) <= 1.0


def test_a_pixel_dataset_is_its_state_dataset_rendered(key_data, tmp_path):
    ds, px = key_data
    assert px.task == "key_pixels" and px.states.dtype == np.uint8 and px.states.shape == (60, 100, 3072)
    np.testing.assert_array_equal(px.returns, ds.returns)
    np.testing.assert_array_equal(px.rewards, ds.rewards)
    np.testing.assert_array_equal(px.privileged, ds.states)
    assert px.final_states.shape == (60, 3072)
    back = TrajectoryDataset.load(px.save(tmp_path / "px"))
    assert back.states.dtype == np.uint8
    np.testing.assert_array_equal(back.states, px.states)
    np.testing.assert_array_equal(back.privileged, px.privileged)
    both = concatenate([px.subset(np.arange(10)), px.subset(np.arange(10, 20))])
    np.testing.assert_array_equal(both.privileged, px.privileged[:20])
    with pytest.raises(ValueError, match="rendered from a key dataset"):
        pixel_dataset(generate_screened("timer", 5, seed=0), "key_pixels")


def test_pixels_are_normalised_by_a_fixed_shift_the_vector_by_the_data(key_data):
    _, px = key_data
    shift, scale = normalisation(px, "standard", image_values=3072)
    assert shift.shape == (3072,) and np.all(shift == 127.5) and np.all(scale == 127.5)
    assert load_train_config("key_pixels") == load_train_config("key")  # a pixel task takes its state task's


@pytest.mark.parametrize("arch", ARCHITECTURES)
def test_every_architecture_reads_images_alike_batched_per_member_and_online(arch, key_data):
    _, px = key_data
    cfg = model_config(arch, "key_pixels", px.state_size, dropout=0.1)
    assert cfg.image_shape == (IMAGE_SIZE, IMAGE_SIZE, 3) and cfg.encoded_size == 8 * 8 * 8
    ens = init_ensemble(cfg, [0, 1, 2]).eval()
    ens.input_shift.fill_(127.5)
    ens.input_scale.fill_(127.5)
    bags = BagTensors(px.subset(np.arange(4)))
    x, lengths, _ = bags.batch(torch.arange(4))
    assert x.dtype == torch.uint8
    with torch.no_grad():
        out = ens(x, lengths)
        same = ens(x.float(), lengths)  # float pixels: the same model
        member = ens.member(1)(x.float(), lengths)
    torch.testing.assert_close(out.rewards, same.rewards)
    torch.testing.assert_close(out.rewards[1], member.rewards, atol=1e-5, rtol=1e-5)
    online = OnlineRewardModel(ens, served="h")
    n = int(px.lengths[0])
    rewards = online.episode_rewards(px.states[0, :n].astype(np.float64))
    np.testing.assert_allclose(rewards, out.rewards.mean(0)[0, :n].numpy(), atol=1e-5)


def test_a_pixel_model_trains_saves_and_serves(key_data, tmp_path):
    _, px = key_data
    cfg = load_train_config("key_pixels", max_epochs=2, threads=1)
    run = fit(px, "csc_lstm", cfg, members=2, out=tmp_path / "pixels", progress=False)
    assert run.meta.metrics["epochs_run"] == 2
    model, meta = load_checkpoint(tmp_path / "pixels", task="key_pixels")
    assert model.config.image_shape == (IMAGE_SIZE, IMAGE_SIZE, 3)
    online = OnlineRewardModel.from_checkpoint(tmp_path / "pixels", task="key_pixels")
    n = int(px.lengths[0])
    rewards = online.episode_rewards(px.states[0, :n].astype(np.float64))
    with torch.no_grad():
        batched = model(torch.as_tensor(px.states[:1, :n]), torch.tensor([n])).rewards.mean(0)[0]
    np.testing.assert_allclose(rewards, batched.numpy(), atol=1e-5)


def test_image_configs_that_do_not_fit_are_one_line_errors():
    with pytest.raises(ValueError, match="patch size 5 must divide"):
        build_model(ModelConfig("csc_lstm", 3072, image_shape=(32, 32, 3), patch=5))
    with pytest.raises(ValueError, match="does not fit a state of 100"):
        build_model(ModelConfig("csc_lstm", 100, image_shape=(32, 32, 3)))
    with pytest.raises(ValueError, match="at least one channel"):
        build_model(ModelConfig("csc_lstm", 3072, image_shape=(32, 32, 3), patch_channels=0))
    config = ModelConfig("csc_lstm", 3072, image_shape=(32, 32, 3))
    assert ModelConfig.from_dict(config.to_dict()) == config
    old = {k: v for k, v in config.to_dict().items() if k not in ("image_shape", "patch", "patch_channels")}
    assert ModelConfig.from_dict(old).image_shape == ()  # a checkpoint from before images


def test_agents_on_a_pixel_task_are_judged_on_the_true_position():
    from nmrm_ros.rl.wrappers import make_reward_env

    oracle_env, state_env = make_reward_env("key_pixels", "oracle", seed=4), make_reward_env("key", "oracle", seed=4)
    obs, _ = oracle_env.reset()
    plain, _ = state_env.reset()
    assert obs.shape == (3072 + 1,)  # the image and the oracle's hidden state
    np.testing.assert_array_equal(obs[-1:], plain[-1:])
    actions = np.random.default_rng(0).integers(0, 5, 100)
    total = [0.0, 0.0]
    for a in actions:
        for i, env in enumerate((oracle_env, state_env)):
            _, reward, _, truncated, info = env.step(int(a))
            total[i] += reward
    assert total[0] == total[1] and info["oracle_return"] == total[1]


@pytest.fixture
def camera_module(tmp_path, monkeypatch):
    """A user's env whose observation is a camera image (or a Dict of an image and a vector),
    with the true pose in info["pose"], and an oracle of the pose: +1 a step on the right half
    once x <= 0.25 was visited."""
    import sys
    import textwrap

    (tmp_path / "camera_room.py").write_text(textwrap.dedent('''
        import gymnasium as gym
        import numpy as np

        class CameraRoom(gym.Env):
            def __init__(self, with_vector=False, height=24, width=32):
                self.h, self.w, self.with_vector = height, width, with_vector
                camera = gym.spaces.Box(0, 255, (height, width, 3), np.uint8)
                self.observation_space = (gym.spaces.Dict({"camera": camera, "battery": gym.spaces.Box(0, 1, (1,))})
                                          if with_vector else camera)
                self.action_space = gym.spaces.Discrete(3)
            def _obs(self):
                image = np.zeros((self.h, self.w, 3), np.uint8)
                image[self.h // 2, int(self.x * (self.w - 1))] = 255
                if self.with_vector:
                    return {"camera": image, "battery": np.array([1 - self.t / 20], np.float32)}
                return image
            def reset(self, *, seed=None, options=None):
                super().reset(seed=seed)
                self.x, self.t = float(self.np_random.uniform(0.3, 0.7)), 0
                return self._obs(), {"pose": [self.x, 0.5]}
            def step(self, action):
                self.x = float(np.clip(self.x + 0.1 * (action - 1), 0, 1))
                self.t += 1
                return self._obs(), 0.0, False, self.t >= 20, {"pose": [self.x, 0.5]}

        def oracle(states, actions):
            seen = np.maximum.accumulate(states[:, 0] <= 0.25)
            return (seen & (states[:, 0] > 0.5)).astype(float)
    '''))
    monkeypatch.syspath_prepend(str(tmp_path))
    yield "camera_room"
    sys.modules.pop("camera_room", None)


def test_a_users_camera_env_is_an_image_task(camera_module):
    from nmrm_ros.datasets.return_screening import screen_by_return
    from nmrm_ros.oracles import make_oracle

    task = "camera_room:CameraRoom,max_steps=20,image=16x16,privileged=pose"
    info = task_info(task)
    assert info.image_shape == (16, 16, 3) and info.state_size == 768 and info.privileged_size == 2
    env = make_env(task)
    obs, first = env.reset(seed=0)
    assert obs.shape == (768,) and 0 < obs.max() <= 255 and first["privileged"].shape == (2,)
    mixed = task_info("camera_room:CameraRoom,with_vector=true,max_steps=20,privileged=pose")
    assert mixed.image_shape == (24, 32, 3) and mixed.state_size == 24 * 32 * 3 + 1
    ds = screen_by_return(task, make_oracle(task, "camera_room:oracle"), 40, pool_size=80, seed=1)
    assert ds.states.dtype == np.uint8 and ds.privileged.shape == (40, 20, 2)
    assert ds.returns.max() > 0  # labelled from the pose, which the image shows only coarsely
    cfg = model_config("csc_lstm", task, ds.state_size)
    assert (cfg.image_shape, cfg.patch) == ((16, 16, 3), 2)
    run = fit(ds, "csc_lstm", load_train_config(task, max_epochs=1, threads=1), members=1, progress=False)
    assert run.model.config.image_shape == (16, 16, 3)


@pytest.mark.parametrize("spec, message", [
    ("camera_room:CameraRoom,max_steps=20,image=0x16", "image must be a size HxW"),
    ("camera_room:CameraRoom,max_steps=20,image=big", "image must be a size HxW"),
    ("camera_room:CameraRoom,max_steps=20,privileged=nothing", "info has no 'nothing'"),
    ("gym:CartPole-v1,image=16x16", "holds no image"),
])
def test_bad_image_specs_are_one_line_errors(camera_module, spec, message):
    from nmrm_ros.tasks.gym_task import TaskSpecError

    with pytest.raises(TaskSpecError, match=message) as err:
        task_info(spec)
    assert "\n" not in str(err.value)


def test_the_minigrid_example_is_a_camera_task_with_a_memory_oracle(monkeypatch):
    from pathlib import Path

    from nmrm_ros.datasets.return_screening import screen_by_return
    from nmrm_ros.oracles import make_oracle

    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1] / "examples"))
    task = "minigrid_corners:make_env,max_steps=60,privileged=pose"
    info = task_info(task)
    assert info.image_shape == (48, 48, 3) and info.privileged_size == 3 and info.action_size == 3
    assert info.instruction.startswith("The red triangle")
    ds = screen_by_return(task, make_oracle(task, "minigrid_corners:oracle"), 10, pool_size=30, seed=2)
    assert ds.states.dtype == np.uint8 and ds.privileged.shape[2] == 3
    x, y = ds.privileged[..., 0], ds.privileged[..., 1]
    for i in range(len(ds)):  # the oracle pays the bottom-left only after the top-right
        n = int(ds.lengths[i])
        visited = np.maximum.accumulate((x[i, :n] >= 3) & (y[i, :n] <= 2))
        assert ds.returns[i] == float((visited & (x[i, :n] <= 2) & (y[i, :n] >= 3)).sum())
    assert model_config("csc_lstm", task, ds.state_size).patch == 6


def test_an_agent_may_see_the_privileged_state_while_the_model_sees_pixels(key_data, tmp_path):
    from nmrm_ros.rl import evaluate_agent, train_agent
    from nmrm_ros.rl.wrappers import make_reward_env

    _, px = key_data
    fit(px, "csc_lstm", load_train_config("key_pixels", max_epochs=1, threads=1), out=tmp_path / "m", progress=False)
    env = make_reward_env("key_pixels", "model", tmp_path / "m", seed=0, observe="privileged")
    obs, info = env.reset()
    assert obs.shape == (2 + env.stepper.served_size,)
    np.testing.assert_array_equal(obs[:2], info["privileged"])
    run = train_agent("key_pixels", "model", tmp_path / "m", episodes=2, out=tmp_path / "agent", progress=False,
                      observe="privileged", learning_starts=10)
    assert run.out is not None
    result = evaluate_agent(tmp_path / "agent" / "policy.zip", "key_pixels", episodes=2)  # observe from agent.json
    assert len(result.returns) == 2
    with pytest.raises(ValueError, match="no privileged state"):
        make_reward_env("key", "oracle", observe="privileged")


def test_an_agent_that_sees_the_image_reads_it_with_a_cnn(key_data, tmp_path):
    """observe state on a pixel task: the policy's features are a CNN of the image's 3072 leading
    values and the served state after them, unchanged; saved, loaded and evaluated as any agent."""
    import torch

    from nmrm_ros.rl import evaluate_agent, train_agent
    from nmrm_ros.rl.image_features import ImageStateExtractor
    from stable_baselines3 import DQN

    _, px = key_data
    fit(px, "csc_lstm", load_train_config("key_pixels", max_epochs=1, threads=1), out=tmp_path / "m", progress=False)
    train_agent("key_pixels", "model", tmp_path / "m", episodes=2, out=tmp_path / "agent", progress=False,
                learning_starts=10)
    model = DQN.load(tmp_path / "agent" / "policy.zip", device="cpu")
    extractor = model.q_net.features_extractor
    assert isinstance(extractor, ImageStateExtractor) and extractor.image_shape == (32, 32, 3)
    obs = torch.rand(5, model.observation_space.shape[0]) * 255
    features = extractor(obs)
    assert features.shape == (5, 128 + model.observation_space.shape[0] - 3072)
    np.testing.assert_array_equal(features[:, 128:].detach().numpy(), obs[:, 3072:].numpy())  # the served state as is
    assert len(evaluate_agent(tmp_path / "agent" / "policy.zip", "key_pixels", episodes=2).returns) == 2
    with pytest.raises(ValueError, match="does not start with a 32x32x3 image"):
        import gymnasium as gym

        ImageStateExtractor(gym.spaces.Box(0, 1, (10,)), (32, 32, 3))


@pytest.mark.parametrize("arch", ARCHITECTURES)
def test_pixels_stored_in_the_encoders_order_train_exactly_as_the_states_hold_them(arch, key_data):
    """BagTensors(ds, model.patch_layout) keeps the pixels patch after patch (no strided copy a
    step): the same outputs and gradients, bit for bit, as the states as they are."""
    _, px = key_data
    ens = init_ensemble(model_config(arch, "key_pixels", px.state_size, dropout=0.1), [0, 1, 2])
    index = torch.as_tensor(np.random.default_rng(0).integers(0, len(px), (3, 5)))
    results = []
    for bags in (BagTensors(px), BagTensors(px, ens.patch_layout)):
        x, lengths, _ = bags.batch(index)
        assert x.shape == (3, 5, int(lengths.max()), px.state_size) and x.dtype == torch.uint8
        ens.zero_grad()
        torch.manual_seed(0)  # the same dropout masks
        out = ens.train()(x, lengths, patch_ordered=bags.patch_ordered)
        out.returns.sum().backward()
        results.append((out.rewards.detach(), [p.grad.clone() for p in ens.parameters()]))
    assert not BagTensors(px).patch_ordered and BagTensors(px, ens.patch_layout).patch_ordered
    assert torch.equal(results[0][0], results[1][0])
    assert all(torch.equal(a, b) for a, b in zip(results[0][1], results[1][1]))


@pytest.mark.parametrize("chunk_values", [48, 5 * 4 * 48, 2 ** 18])  # one instance, 5 (a remainder), all
def test_the_patch_layer_converts_in_chunks_what_autograd_computes_at_once(chunk_values, monkeypatch):
    from nmrm_ros.mil import image_encoder

    monkeypatch.setattr(image_encoder, "CHUNK_VALUES", chunk_values)
    gen = torch.Generator().manual_seed(0)
    pixels = torch.randint(0, 256, (2, 13, 4, 48), dtype=torch.uint8, generator=gen)  # K 2, N 13, P 4
    weights = [torch.randn(2, 8, 48, generator=gen).div(100).requires_grad_(),
               torch.randn(2, 8, generator=gen).requires_grad_()]
    upstream = torch.randn(2, 13 * 4, 8, generator=gen)
    ours = image_encoder.PatchLayer.apply(pixels, *weights)
    (ours * upstream).sum().backward()
    grads = [w.grad.clone() for w in weights]
    for w in weights:
        w.grad = None
    reference = torch.relu(pixels.float().view(2, 52, 48) @ weights[0].transpose(1, 2) + weights[1][:, None, :])
    (reference * upstream).sum().backward()
    torch.testing.assert_close(ours, reference)
    for ours_grad, w in zip(grads, weights):
        torch.testing.assert_close(ours_grad, w.grad, rtol=1e-4, atol=1e-3)  # sums of ~1000 terms of pixels <= 255


def test_two_losses_of_a_pixel_ensemble_before_one_backward(key_data):
    """feedback both: a return batch and a comparison batch, then one backward. The second
    forward must not overwrite the pixels the first one's backward reads."""
    _, px = key_data
    cfg = model_config("csc_lstm", "key_pixels", px.state_size)
    x = torch.as_tensor(px.states[:6])
    lengths = torch.as_tensor(px.lengths[:6])
    grads = []
    for together in (False, True):
        ens = init_ensemble(cfg, [0, 1])
        ens.input_shift.fill_(127.5)
        ens.input_scale.fill_(127.5)
        if together:
            loss = ens(x[:3], lengths[:3]).returns.sum() + ens(x[3:], lengths[3:]).returns.sum()
            loss.backward()
        else:
            ens(x[:3], lengths[:3]).returns.sum().backward()
            ens(x[3:], lengths[3:]).returns.sum().backward()
        grads.append(ens.params["encoder__weight"].grad.clone())
    torch.testing.assert_close(grads[0], grads[1])


def test_a_pixel_episode_recorded_and_read_back_keeps_its_privileged_state(key_data, tmp_path):
    from nmrm_ros.bags.episodes import load_bag_dataset, write_dataset_bag

    _, px = key_data
    part = px.subset(np.arange(5))
    write_dataset_bag(part, tmp_path / "bag")
    back, report = load_bag_dataset([tmp_path / "bag"])
    assert report.episodes_used == 5
    np.testing.assert_array_equal(back.states, part.states.astype(np.float32))
    np.testing.assert_array_equal(back.privileged, part.privileged)
    np.testing.assert_array_equal(back.returns, part.returns)
    # no frames for people beside the images: the labelling page and the LeRobot export draw
    # them from the observation images (each pixel a 4 x 4 block)
    from nmrm_ros.bags.reader import bag_summary
    from nmrm_ros.lerobot.to_lerobot import export_lerobot
    from nmrm_ros.lerobot.video import read_frames
    from nmrm_ros.tasks.frames import image_state_frame

    assert "/nmrm/frame" not in bag_summary(tmp_path / "bag")
    report = export_lerobot([tmp_path / "bag"], tmp_path / "lerobot", progress=False)
    assert report.camera == "observation.images.render (h264 video, of the observation images)"
    _, first = next(read_frames(sorted((tmp_path / "lerobot").rglob("*.mp4"))[0]))
    shown = image_state_frame(part.states[0, 0], (32, 32, 3)).astype(float)
    assert first.shape == (128, 128, 3) and np.abs(first - shown).mean() < 4  # H.264's loss


def test_explain_draws_a_pixel_models_views_at_the_positions_behind_its_images(key_data, tmp_path, camera_module):
    """`nmrm explain` of a pixel Key model: the state task's views (maps, probes, embedding, a bag's
    episodes), the model reading the image of each position; a camera task, whose images have no
    positions to draw them at, is refused in one line."""
    import subprocess
    import sys

    from nmrm_ros.bags.episodes import write_dataset_bag
    from nmrm_ros.interpret import explain
    from nmrm_ros.interpret.episode_view import read_episodes
    from nmrm_ros.interpret.reward_maps import context_prefixes, grid, learnt_reward_map
    from nmrm_ros.interpret.traces import pixel_inputs
    from nmrm_ros.tasks.pixel_navigation import pixel_states

    ds, px = key_data
    run = fit(px, "csc_lstm", load_train_config("key_pixels", max_epochs=1, threads=1), out=tmp_path / "m",
              progress=False)
    # a reward map of the pixel model is its online stepper on the images of the prefix and of each point
    label, prefix = context_prefixes("key")[1]
    n = 5
    learnt = learnt_reward_map(run.model, prefix, n, "key", pixel_inputs("key_pixels"))
    online = OnlineRewardModel(run.model)
    for i, point in enumerate(grid(n, "key")[2][:7]):
        images = pixel_states("key", np.vstack([prefix, point[None]]))
        assert learnt.ravel()[i] == pytest.approx(online.episode_rewards(images)[-1], abs=1e-4)
    # a bag of pixel episodes: the oracle judges the recorded positions
    bag = write_dataset_bag(px.subset(np.arange(4)), tmp_path / "bag")
    rec = next(iter(read_episodes(bag).values()))
    np.testing.assert_array_equal(rec.privileged, ds.states[0, :ds.lengths[0]].astype(np.float32))
    np.testing.assert_allclose(rec.oracle, ds.rewards[0, :ds.lengths[0]])
    out = tmp_path / "views"
    result = subprocess.run([sys.executable, "-m", "nmrm_ros.cli", "explain", "--checkpoint", str(run.checkpoint),
                             "--bag", str(bag), "--out", str(out), "--episodes", "1"],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in out.glob("*.png")) == [
        "episode_root_0.png", "hidden_embedding.png", "probe_key_first.png", "probe_no_key.png", "reward_maps.png"]
    assert "read the image of each position" in (out / "index.html").read_text()
    # a camera task: no positions behind its images to draw the views at
    task = "camera_room:CameraRoom,max_steps=20,image=16x16,privileged=pose"
    cam = build_model(model_config("csc_lstm", task, 768))
    from nmrm_ros.mil import Run

    path = Run.of(cam.eval(), task).save(tmp_path / "cam")
    with pytest.raises(ValueError, match="only the pixel navigation tasks"):
        explain(path, tmp_path / "cam_views", n=4)


@pytest.fixture
def encoder_module(camera_module, tmp_path):
    """A user's image encoder (a conv layer and an FC layer to 6 features) and its weights file."""
    import importlib
    import textwrap

    (tmp_path / "my_encoder.py").write_text(textwrap.dedent('''
        import torch

        class Encoder(torch.nn.Module):
            def __init__(self):
                super().__init__()
                self.conv = torch.nn.Conv2d(3, 4, 4, stride=4)
                self.out = torch.nn.Linear(4 * 4 * 4, 6)
            def forward(self, x):
                return self.out(torch.relu(self.conv(x)).flatten(1))

        def broken():
            raise RuntimeError("no GPU here")

        class Normalising(Encoder):
            def forward(self, x):  # each image standardised: a uniform image has no features
                return super().forward((x - x.mean()) / x.std())
    '''))
    (tmp_path / "raising_encoder.py").write_text("raise ValueError('needs a licence key')\n")
    module = importlib.import_module("my_encoder")
    torch.manual_seed(0)
    encoder = module.Encoder()
    torch.save(encoder.state_dict(), tmp_path / "enc.pt")
    torch.save({"x": torch.zeros(2)}, tmp_path / "other.pt")
    yield encoder.eval()
    import sys

    sys.modules.pop("my_encoder", None)


def test_a_users_frozen_encoder_makes_a_camera_task_a_vector_task(encoder_module, tmp_path):
    """encoder=<module>:<attribute>,encoder_weights=<file>: the image's part of the state is the
    frozen encoder's features of each frame (computed as the env steps), so datasets, models and
    agents see a vector."""
    from nmrm_ros.datasets.return_screening import screen_by_return
    from nmrm_ros.oracles import make_oracle

    camera = "camera_room:CameraRoom,max_steps=20,image=16x16,privileged=pose"
    task = f"{camera},encoder=my_encoder:Encoder,encoder_weights={tmp_path / 'enc.pt'}"
    info = task_info(task)
    assert (info.image_shape, info.state_size, info.privileged_size) == ((), 6, 2)
    obs, first = make_env(task).reset(seed=0)
    image = make_env(camera).reset(seed=0)[0].reshape(16, 16, 3)
    with torch.no_grad():
        expected = encoder_module(torch.from_numpy(image).permute(2, 0, 1)[None].float() / 255).reshape(-1)
    np.testing.assert_allclose(obs, expected.numpy(), rtol=1e-5, atol=1e-6)
    assert first["privileged"].shape == (2,)
    mixed = task_info("camera_room:CameraRoom,with_vector=true,max_steps=20,privileged=pose,"
                      "encoder=my_encoder:Encoder,image=16x16")
    assert mixed.state_size == 6 + 1 and mixed.image_shape == ()
    # without weights: the same (seed 0) random module in every env and process; a module that
    # standardises each image is fine (its size is probed on noise, not on a uniform image)
    bare = f"{camera},encoder=my_encoder:Normalising"
    first, second = make_env(bare).reset(seed=0)[0], make_env(bare).reset(seed=0)[0]
    np.testing.assert_array_equal(first, second)
    assert task_info(bare).state_size == 6
    ds = screen_by_return(task, make_oracle(task, "camera_room:oracle"), 40, pool_size=80, seed=1)
    assert ds.states.shape[-1] == 6 and ds.privileged.shape == (40, 20, 2)
    run = fit(ds, "csc_lstm", load_train_config(task, max_epochs=1, threads=1), progress=False)
    assert run.model.config.image_shape == () and run.model.config.input_size == 6
    # the checkpoint records the encoder weights' SHA-256; once the file holds other weights,
    # loading the model is refused in one line (its states would be another encoder's features)
    from nmrm_ros.mil import Run
    from nmrm_ros.mil.checkpoint import CheckpointError

    path = run.save(tmp_path / "frozen_model")
    assert Run.load(path).meta.encoder_sha256 == hashlib.sha256((tmp_path / "enc.pt").read_bytes()).hexdigest()
    kept = (tmp_path / "enc.pt").read_bytes()
    torch.manual_seed(1)
    torch.save(type(encoder_module)().state_dict(), tmp_path / "enc.pt")
    with pytest.raises(CheckpointError, match="trained on states of another encoder .*enc.pt were of SHA-256 .*restore"):
        Run.load(path)
    # the dataset records it too (its states are those features): training on it is refused, and
    # a cached copy is stale
    from nmrm_ros.datasets.cache import stale_data

    assert ds.meta["encoder_sha256"] == hashlib.sha256(kept).hexdigest()
    with pytest.raises(ValueError, match="features of another encoder .*make the dataset again"):
        fit(ds, "csc_lstm", load_train_config(task, max_epochs=1, threads=1), progress=False)
    assert stale_data(ds.meta, task) and "now holds" in stale_data(ds.meta, task)[0]
    (tmp_path / "enc.pt").write_bytes(kept)
    assert Run.load(path).model.config.input_size == 6 and stale_data(ds.meta, task) == []


def test_a_camera_bag_is_read_through_a_frozen_encoder_named_afterwards(encoder_module, tmp_path):
    """Episodes recorded with a camera task (pixels as observation images) are read as the same
    spec with a frozen encoder: each image becomes the encoder's features, as if recorded with it
    (the same states as the encoder task's own dataset of those episodes); an encoder that does
    not fit the images is a one-line error."""
    from nmrm_ros.bags import BagError
    from nmrm_ros.bags.episodes import load_bag_dataset, write_dataset_bag
    from nmrm_ros.datasets.return_screening import screen_by_return
    from nmrm_ros.oracles import make_oracle

    camera = "camera_room:CameraRoom,max_steps=20,image=16x16,privileged=pose"
    task = f"{camera},encoder=my_encoder:Encoder,encoder_weights={tmp_path / 'enc.pt'}"
    recorded = screen_by_return(camera, make_oracle(camera, "camera_room:oracle"), 6, pool_size=20, seed=1)
    bag = write_dataset_bag(recorded, tmp_path / "camera_bag")
    back, report = load_bag_dataset([bag], task=task)
    direct = screen_by_return(task, make_oracle(task, "camera_room:oracle"), 6, pool_size=20, seed=1)
    assert report.episodes_used == 6 and back.task == task and back.meta["encoded_from"] == camera
    assert back.meta["encoder_sha256"] == hashlib.sha256((tmp_path / "enc.pt").read_bytes()).hexdigest()
    np.testing.assert_array_equal(back.returns, direct.returns)
    np.testing.assert_allclose(back.states, direct.states, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(back.final_states, direct.final_states, rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(back.privileged, direct.privileged)
    with pytest.raises(BagError, match="read as .*other.pt"):
        load_bag_dataset([bag], task=f"{camera},encoder=my_encoder:Encoder,encoder_weights={tmp_path / 'other.pt'}")


@pytest.mark.parametrize("tail, message", [
    ("encoder=my_encoder:Nope", "'my_encoder' has no 'Nope'"),
    ("encoder=no_such_module_here:E", "cannot import 'no_such_module_here'"),
    ("encoder=my_encoder:broken", "building it failed: RuntimeError: no GPU here"),
    ("encoder=my_encoder:Encoder,encoder_weights={tmp}/missing.pt", "cannot read encoder_weights"),
    ("encoder=my_encoder:Encoder,encoder_weights={tmp}/other.pt", "do not fit it"),
    ("encoder=my_encoder", "encoder must be <module>:<attribute>"),
    ("encoder=raising_encoder:E", "cannot import 'raising_encoder' \\(ValueError: needs a licence key\\)"),
    ("encoder_weights={tmp}/enc.pt", "encoder_weights without encoder"),
])
def test_a_frozen_encoder_that_does_not_load_is_a_one_line_error(encoder_module, tmp_path, tail, message):
    import subprocess
    import sys

    task = f"camera_room:CameraRoom,max_steps=20,image=16x16,{tail.format(tmp=tmp_path)}"
    with pytest.raises(ValueError, match=message):
        task_info(task)
    if "missing.pt" in tail:  # at the command line: one line, exit code 2
        import os

        env = dict(os.environ, PYTHONPATH=str(tmp_path))
        result = subprocess.run([sys.executable, "-m", "nmrm_ros.cli", "dataset", "generate", "--task", task,
                                 "--oracle", "camera_room:oracle", "--episodes", "4", "--out", str(tmp_path / "bag")],
                                capture_output=True, text=True, timeout=120, env=env)
        assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1, result.stderr
        assert "cannot read encoder_weights" in result.stderr
    with pytest.raises(ValueError, match="holds no image"):
        task_info("gym:CartPole-v1,encoder=my_encoder:Encoder")
