"""An image task's pixels travel as a PNG beside the step messages (nmrm/observation_image):
encoding, joining them again in any order, and bags that hold them (or, recorded earlier, not)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nmrm_ros.ros.observation_images import ImagePairing
from nmrm_ros.tasks.frames import frame_id
from nmrm_ros.tasks.image_states import decode_image_state, encode_image_state, vector_part


@settings(max_examples=60, deadline=None)
@given(h=st.integers(1, 12), w=st.integers(1, 12), c=st.integers(1, 7), seed=st.integers(0, 2**31 - 1))
def test_an_image_state_comes_back_exactly_for_any_channels(h, w, c, seed):
    """Lossless for grey, RGB, RGBA, stacked RGB cameras and any other channel count."""
    rng = np.random.default_rng(seed)
    state = np.concatenate([rng.integers(0, 256, h * w * c).astype(np.float32), [0.5, -2.0]])
    pixels = decode_image_state(encode_image_state(state, (h, w, c)), (h, w, c))
    assert pixels.dtype == np.uint8
    np.testing.assert_array_equal(pixels, state[: h * w * c])
    np.testing.assert_array_equal(vector_part(state, (h, w, c)), [0.5, -2.0])


def test_an_observation_image_reads_as_a_picture_of_its_cameras():
    """Two RGB cameras stacked along C are sent one above the other (what Foxglove shows)."""
    import io

    from PIL import Image

    a, b = np.full((4, 5, 3), 10, np.uint8), np.full((4, 5, 3), 200, np.uint8)
    data = encode_image_state(np.concatenate([a, b], axis=2).reshape(-1), (4, 5, 6))
    picture = np.asarray(Image.open(io.BytesIO(data)))
    assert picture.shape == (8, 5, 3) and (picture[:4] == 10).all() and (picture[4:] == 200).all()


@pytest.mark.parametrize("values, message", [
    (np.full(11, 3.0), "needs 12 values"),
    (np.full(12, 256.0), "not whole numbers in 0..255"),
    (np.full(12, 0.5), "not whole numbers in 0..255"),
    (np.full(12, np.nan), "not whole numbers in 0..255"),
])
def test_values_that_are_not_an_image_are_refused_in_one_line(values, message):
    with pytest.raises(ValueError, match=message):
        encode_image_state(values, (2, 2, 3))


def test_an_image_of_another_layout_or_no_image_is_refused_in_one_line():
    data = encode_image_state(np.zeros(12), (2, 2, 3))
    with pytest.raises(ValueError, match="the task's .* is sent as"):
        decode_image_state(data, (3, 2, 3))
    with pytest.raises(ValueError, match="PNG L image"):
        decode_image_state(data, (2, 2, 1))
    with pytest.raises(ValueError, match="cannot be decoded"):
        decode_image_state(b"not a png", (2, 2, 3))


def _image(e, t, pixels, shape=(2, 2, 3)):
    return SimpleNamespace(header=SimpleNamespace(frame_id=frame_id(e, t)), data=encode_image_state(pixels, shape))


def _step(e, t, vector, **fields):
    return SimpleNamespace(episode=e, step=t, state=list(vector), **fields)


def test_a_message_is_delivered_with_its_pixels_whichever_comes_first():
    out = []
    pairing = ImagePairing((2, 2, 3), 14, out.append, fields=("state", "augmented_state"))
    first = np.arange(12, dtype=np.float32)
    pairing.on_message(_step(0, 0, [1.0, 2.0], augmented_state=[1.0, 2.0, 0.5]))  # before its image
    assert out == []
    pairing.on_image(_image(0, 0, first))
    pairing.on_image(_image(0, 1, first + 100))
    pairing.on_message(_step(0, 1, [3.0, 4.0], augmented_state=[3.0, 4.0, -0.5]))  # after its image
    pairing.on_message(_step(0, 1, [3.0, 4.0], augmented_state=[3.0, 4.0, -0.5]))  # re-published: again
    assert [(m.episode, m.step) for m in out] == [(0, 0), (0, 1), (0, 1)]
    np.testing.assert_array_equal(out[0].state, np.concatenate([first, [1.0, 2.0]]))
    np.testing.assert_array_equal(out[0].augmented_state, np.concatenate([first, [1.0, 2.0, 0.5]]))
    np.testing.assert_array_equal(out[2].state, np.concatenate([first + 100, [3.0, 4.0]]))
    # a whole state (a bag recorded before the pixels travelled apart) and a wrong size pass as they are
    whole = _step(0, 2, np.arange(14))
    wrong = _step(0, 3, [1.0])
    pairing.on_message(whole)
    pairing.on_message(wrong)
    assert out[-2] is whole and out[-1] is wrong and len(out[-1].state) == 1
    assert pairing.unpaired == pairing.bad_images == 0


def test_images_that_are_refused_and_steps_that_never_get_theirs_are_counted():
    out, errors = [], []
    pairing = ImagePairing((2, 2, 3), 12, out.append, capacity=2, on_error=errors.append)
    pairing.on_image(SimpleNamespace(header=SimpleNamespace(frame_id="camera"), data=b""))
    pairing.on_image(SimpleNamespace(header=SimpleNamespace(frame_id=frame_id(0, 0)), data=b"junk"))
    assert pairing.bad_images == 2 and "names no step" in errors[0] and "cannot be decoded" in errors[1]
    for t in range(3):  # none of them gets its image: the oldest beyond capacity is dropped
        pairing.on_message(_step(0, t, []))
    assert pairing.unpaired == 1 and out == []
    pairing.on_image(_image(0, 2, np.zeros(12)))
    assert [m.step for m in out] == [2]


def test_a_bag_of_an_image_task_holds_pngs_and_reads_back_whole_states(tmp_path):
    """write_dataset_bag sends the pixels as observation images (observations carry what follows
    them); an episode whose image is missing is skipped as missing_image; a bag recorded before,
    with whole states, reads as it did."""
    from nmrm_ros.bags.episodes import load_bag_dataset, stamped_header, write_dataset_bag
    from nmrm_ros.bags.reader import iter_decoded, iter_raw
    from nmrm_ros.bags.writer import BagWriter
    from nmrm_ros.datasets import generate_screened
    from nmrm_ros.tasks.pixel_navigation import pixel_dataset

    ds = pixel_dataset(generate_screened("key", 3, seed=5, pool_size=60), "key_pixels")
    bag = write_dataset_bag(ds, tmp_path / "bag")
    messages = list(iter_decoded(bag))
    observations = [m for topic, _, _, m in messages if topic == "/nmrm/observation"]
    images = [m for topic, _, _, m in messages if topic == "/nmrm/observation_image"]
    assert all(len(m.state) == 0 for m in observations) and len(images) == len(observations)
    assert {m.format for m in images} == {"png"}
    back, report = load_bag_dataset([bag])
    assert report.episodes_used == 3
    np.testing.assert_array_equal(back.states, ds.states.astype(np.float32))
    np.testing.assert_array_equal(back.final_states, ds.final_states.astype(np.float32))

    # the same episodes with episode 1's image of step 4 lost, and episode 2 as older bags hold it
    with BagWriter(tmp_path / "edited") as out:
        for (topic, type_name, log_ns, m), raw in zip(messages, iter_raw(bag)):
            if topic == "/nmrm/observation_image" and m.header.frame_id == frame_id(1, 4):
                continue
            if topic == "/nmrm/observation_image" and m.header.frame_id.startswith("nmrm_episode_2_"):
                continue
            if topic == "/nmrm/observation" and m.episode == 2:
                whole = ds.final_states[2] if m.truncated else ds.states[2, m.step]
                out.write_dict(topic, type_name, {
                    "header": stamped_header(log_ns, m.task), "task": m.task, "episode": m.episode, "step": m.step,
                    "state": [float(x) for x in whole], "terminated": m.terminated, "truncated": m.truncated,
                    "privileged": list(m.privileged)}, log_ns)
                continue
            out.write_cdr(topic, type_name, raw.data, log_ns)
    back, report = load_bag_dataset([tmp_path / "edited"])
    assert report.episodes_used == 2 and report.skipped == {"missing_image": 1}
    np.testing.assert_array_equal(back.states, ds.states[[0, 2]].astype(np.float32))
