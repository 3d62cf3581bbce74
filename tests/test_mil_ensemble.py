"""Ensembles: the batched forward equals each member's own, one-pass training equals training each
member alone, checkpoints round-trip, the online ensemble step equals the batched forward, and the
training report says when a run stopped while still improving."""

import json

import numpy as np
import pytest
import torch

from nmrm_ros.datasets import make_toy_dataset
from nmrm_ros.mil import (ARCHITECTURES, CheckpointError, OnlineRewardModel, build_model,
                          load_checkpoint, load_train_config, model_config, train_model)
from nmrm_ros.mil.data import split_indices
from nmrm_ros.mil.ensemble import MILEnsemble, init_ensemble
from nmrm_ros.mil.pipeline import fit, member_splits
from nmrm_ros.mil.served_state import served_states
from nmrm_ros.mil.training import train_ensemble


def _members(arch, task="key", d=2, k=3, hidden_size=2):
    models = []
    for m in range(k):
        torch.manual_seed(10 + m)
        model = build_model(model_config(arch, task, d, dropout=0.1, hidden_size=hidden_size))
        model.set_normalisation(torch.rand(d), torch.rand(d) + 0.5, 1.0)
        if model.uses_lstm:
            with torch.no_grad():
                model.h0.uniform_(-0.5, 0.5)
                model.c0.uniform_(-0.5, 0.5)
        models.append(model.eval())
    return models


@pytest.mark.parametrize("arch", ARCHITECTURES)
@pytest.mark.parametrize("task,d,hidden_size", [("key", 2, 2), ("lunar_lander", 8, 2), ("key", 2, 8)])
def test_ensemble_forward_equals_each_members_forward(arch, task, d, hidden_size):
    """Also for an LSTM wide enough (4k >= features) that the ensemble feeds it the features
    through block-diagonal input weights instead of precomputed gate inputs."""
    models = _members(arch, task, d, hidden_size=hidden_size)
    ens = MILEnsemble.from_members(models).eval()
    x = torch.randn(3, 5, 17, d)
    lengths = torch.randint(1, 18, (3, 5))
    out = ens(x, lengths)  # one batch per member
    shared = ens(x[0], lengths[0])  # one batch for all
    for m, model in enumerate(models):
        own = model(x[m], lengths[m])
        torch.testing.assert_close(out.returns[m], own.returns, atol=1e-5, rtol=1e-5)
        torch.testing.assert_close(out.rewards[m], own.rewards, atol=1e-6, rtol=1e-5)
        torch.testing.assert_close(out.hidden[m], own.hidden, atol=1e-6, rtol=1e-5)
        torch.testing.assert_close(shared.rewards[m], model(x[0], lengths[0]).rewards, atol=1e-6, rtol=1e-5)
        # member() rebuilds exactly the model that went in
        for (name, a), b in zip(model.state_dict().items(), ens.member(m).state_dict().values()):
            assert torch.equal(a, b), name


@pytest.mark.parametrize("arch", ARCHITECTURES)
def test_a_forward_of_some_members_is_those_members_of_the_whole_forward(arch):
    """ens(x, lengths, members=idx): the rows idx of the whole ensemble's outputs, exactly; in
    training, the dropout masks of those members only (each from its own stream)."""
    from nmrm_ros.mil.dropout import MemberDropout

    ens = MILEnsemble.from_members(_members(arch, k=4)).eval()
    rng = np.random.default_rng(0)
    x = torch.as_tensor(rng.normal(size=(4, 5, 12, 2)).astype(np.float32))
    lengths = torch.as_tensor(rng.integers(3, 13, size=(4, 5)))
    whole = ens(x, lengths)
    idx = torch.tensor([1, 3])
    some = ens(x[idx], lengths[idx], idx)
    for name in ("returns", "rewards", "hidden"):
        assert torch.equal(getattr(some, name), getattr(whole, name)[idx]), name
    every = MemberDropout(0.1, [0, 1, 2, 3], [4, 3]).take(5, [12, 12, 12, 12])
    picked = MemberDropout(0.1, [0, 1, 2, 3], [4, 3]).take(5, [12, 12], idx)
    for a, b in zip(every, picked):
        assert torch.equal(a[idx], b)


def test_ensemble_training_is_each_member_trained_alone():
    """Two members trained in one pass (dropout 0) end where each one's own run ends."""
    ds = make_toy_dataset("push_switch", 300, seed=0)
    cfg = load_train_config("push_switch", max_epochs=3, dropout=0.0)
    config = model_config("csc_lstm", "push_switch", ds.state_size)
    splits = [split_indices(len(ds), s)[:2] for s in (0, 1)]
    ens = init_ensemble(config, [5, 6])
    train_ensemble(ens, ds, splits, cfg, seeds=[5, 6], progress=False)
    for m, seed in enumerate((5, 6)):
        torch.manual_seed(seed)
        alone = build_model(config)
        tr, va = splits[m]
        alone_cfg = load_train_config("push_switch", max_epochs=3, dropout=0.0, seed=seed)
        train_model(alone, ds.subset(tr), ds.subset(va), alone_cfg, progress=False)
        for (name, a), b in zip(alone.state_dict().items(), ens.member(m).state_dict().values()):
            torch.testing.assert_close(a, b, atol=2e-5, rtol=1e-4, msg=name)


def test_ensemble_checkpoint_and_online_step(tmp_path):
    ds = make_toy_dataset("push_switch", 200, seed=1)
    # 2 epochs: some members not fitted yet (redraws 0: one draw of them)
    cfg = load_train_config("push_switch", max_epochs=2, keep_members="all", redraws=0)
    run = fit(ds, "csc_lstm", cfg, members=4, split_mode="bootstrap", out=tmp_path / "ens", progress=False)
    meta = json.loads((tmp_path / "ens.json").read_text())
    assert meta["ensemble"]["members"] == 4 and meta["ensemble"]["seeds"] == [0, 1, 2, 3]
    serving = meta["ensemble"]["serving_member"]
    assert serving == int(np.argmin([v["return_mse"] for v in run.member_val]))
    loaded, _ = load_checkpoint(tmp_path / "ens", task="push_switch")
    assert isinstance(loaded, MILEnsemble) and loaded.members == 4 and int(loaded.serving_member) == serving
    for a, b in zip(run.model.state_dict().values(), loaded.state_dict().values()):
        assert torch.equal(a, b)
    # online: the members' mean reward, their spread, and the serving member's [h', c']
    states = ds.states[0, : ds.lengths[0]]
    with torch.no_grad():
        out = loaded(torch.as_tensor(states)[None], torch.tensor([len(states)]))
    online = OnlineRewardModel(loaded)
    online.reset()
    served = served_states(loaded, states[None])[0]
    for t in range(len(states)):
        r, h = online.step(states[t])
        members = out.rewards[:, 0, t].double().numpy()
        assert r == pytest.approx(members.mean(), abs=1e-5)
        assert online.reward_std == pytest.approx(members.std(), abs=1e-5)
        np.testing.assert_allclose(h[:2], out.hidden[serving, 0, t].numpy(), atol=1e-6)
        np.testing.assert_allclose(h, served[t], atol=1e-6)
    returns = out.returns[:, 0].double().numpy()
    assert online.return_std == pytest.approx(returns.std(), abs=1e-4)


def test_ensemble_checkpoint_with_wrong_member_count_is_refused(tmp_path):
    ds = make_toy_dataset("push_switch", 100, seed=1)
    fit(ds, "instance_lstm", load_train_config("push_switch", max_epochs=1),
                       members=2, out=tmp_path / "ens", progress=False)
    meta = json.loads((tmp_path / "ens.json").read_text())
    meta["ensemble"]["members"] = 3
    (tmp_path / "ens.json").write_text(json.dumps(meta))
    with pytest.raises(CheckpointError, match="3-member ensemble"):
        load_checkpoint(tmp_path / "ens")


def test_split_modes():
    shared, _ = member_splits(100, 3, 0, "shared")
    assert all(np.array_equal(shared[0][0], s[0]) for s in shared)
    per_member, seeds = member_splits(100, 3, 4, "per_member")
    assert seeds == [4, 5, 6] and not np.array_equal(per_member[0][0], per_member[1][0])
    boot, _ = member_splits(100, 3, 0, "bootstrap")
    train, val, test = split_indices(100, 0)
    for tr, va, te in boot:
        assert len(tr) == len(train) and set(tr) <= set(train) and len(set(tr)) < len(tr)
        assert np.array_equal(va, val) and np.array_equal(te, test)
    with pytest.raises(ValueError, match="unknown split mode"):
        member_splits(100, 3, 0, "nope")


def test_report_says_still_improving_at_the_limit():
    ds = make_toy_dataset("push_switch", 200, seed=2)
    train, val, _ = split_indices(len(ds), 0)
    # at the epoch limit while the validation loss still falls
    model = build_model(model_config("csc_lstm", "push_switch", ds.state_size))
    result = train_model(model, ds.subset(train), ds.subset(val),
                         load_train_config("push_switch", max_epochs=3, patience=10), progress=False)
    assert result.epochs_run == 3 and result.still_improving
    # a plateau (learning rate 0): stops on patience, not still improving
    model = build_model(model_config("csc_lstm", "push_switch", ds.state_size))
    flat = load_train_config("push_switch", max_epochs=50, patience=2)
    flat.lr = 0.0  # below what a config accepts (lr > 0): set here for the test only
    result = train_model(model, ds.subset(train), ds.subset(val), flat, progress=False)
    assert result.best_epoch == 1 and result.epochs_run == 3 and not result.still_improving


def test_wrong_typed_training_setting_is_refused():
    with pytest.raises(ValueError, match="batch_size must be an int"):
        load_train_config("timer", batch_size="many")
    assert load_train_config("timer", lr="1e-3").lr == 1e-3


def test_member_offsets_rerun_chosen_repeats_exactly():
    """offsets=[2] trains what member 2 of a 3-member per-member run trained (seed, split, dropout
    masks, result): how bench/reproduce_tables.py --seeds reruns a table's failing repeats."""
    ds = make_toy_dataset("push_switch", 150, seed=2)
    cfg = load_train_config("push_switch", max_epochs=2, dropout=0.1, keep_members="all")
    full = fit(ds, "csc_lstm", cfg, members=3, split_mode="per_member", split_seed=4, progress=False)
    one = fit(ds, "csc_lstm", cfg, members=1, split_mode="per_member", split_seed=4, progress=False, offsets=[2])
    assert one.seeds == [2] and one.split_seeds == [6]
    assert one.member_test[0]["return_mse"] == pytest.approx(full.member_test[2]["return_mse"], rel=1e-4)
    with pytest.raises(ValueError, match="2 member offsets for 3 members"):
        member_splits(100, 3, 0, "per_member", offsets=[0, 1])


def test_keep_members_best_keeps_the_member_best_on_validation(tmp_path):
    from nmrm_ros.mil import load_checkpoint, load_train_config

    ds = make_toy_dataset("push_switch", 200, seed=0)
    everyone = fit(ds, "csc_lstm", load_train_config("push_switch", max_epochs=3, keep_members="all"), members=3,
                   progress=False)
    cfg = load_train_config("push_switch", max_epochs=3, keep_members="best")
    run = fit(ds, "csc_lstm", cfg, members=3, progress=False, out=tmp_path / "best")
    chosen = int(np.argmin(everyone.train.best_val_loss))
    assert run.model.members == 1 and run.seeds == [chosen] and run.chosen == chosen
    for (name, kept), full in zip(run.model.params.items(), everyone.model.params.values()):
        torch.testing.assert_close(kept[0], full[chosen], msg=name)
    model, meta = load_checkpoint(tmp_path / "best")
    assert model.members == 1 and meta.ensemble.candidates == 3 and meta.ensemble.chosen == chosen
    with pytest.raises(ValueError, match="keep_members"):
        load_train_config("push_switch", keep_members="worst")


def test_fitted_members_leaves_out_only_a_member_that_did_not_fit():
    """The rule on the unexplained validation variances of measured checkpoints (pipeline.py)."""
    from nmrm_ros.mil.fitted import fitted_members

    assert fitted_members([0.999, 0.0015, 0.0004], serving=2) == [1, 2]  # cue corridor, data seed 0
    assert fitted_members([0.999, 0.999, 0.00007], serving=2) == [2]  # cue corridor, data seed 1
    assert fitted_members([0.065, 0.0034, 0.0045], serving=1) == [1, 2]  # Charger, data seed 22
    assert fitted_members([0.0026, 0.00024, 0.0027], serving=1) == [0, 1, 2]  # CartPole: 11x apart, all fit
    assert fitted_members([0.0074, 0.00055, 0.0038], serving=1) == [0, 1, 2]  # delivery: 13x apart, all under 1%
    assert fitted_members([0.076, 0.041, 0.036], serving=2) == [0, 1, 2]  # delivery: all over 1%, 2x apart
    assert fitted_members([1e-5, 2e-5, 0.0], serving=2) == [0, 1, 2]  # MiniGrid: all fit
    assert fitted_members([0.5, 0.02], serving=0) == [0, 1]  # the serving member stays, whatever it scores


def test_the_rule_skips_unlabelled_episodes_and_judges_nothing_without_varied_labels():
    from nmrm_ros.mil.fitted import label_variance, unfitted

    labels = np.arange(10.0)
    labels[3] = np.nan
    assert label_variance(labels) == pytest.approx(np.var(np.delete(labels, 3)))
    assert label_variance(np.array([1.0, np.nan])) == 0.0
    assert unfitted([np.nan, 0.5, 0.001]).tolist() == [False, False, False]  # a member's labels did not vary
    assert unfitted([np.inf, 0.5, 0.001]).tolist() == [True, True, False]  # a member that diverged


def test_a_member_that_cannot_fit_is_done_at_its_first_plateau():
    """keep_members fitted under the plateau schedule: a member whose ReLUs are all dead (it can
    only learn the mean return) is done once it is plateau_patience epochs past its last progress
    and unfitted, while another has learnt the task; that one trains on as it would have."""
    from nmrm_ros.mil.training import initialise

    ds = make_toy_dataset("toggle_switch", 300, seed=0)
    tr, va, _ = split_indices(len(ds), 0)
    config = model_config("csc_lstm", "toggle_switch", ds.state_size)

    def train(keep):
        ens = init_ensemble(config, [0, 1, 2])
        cfg = load_train_config("toggle_switch", schedule="plateau", plateau_patience=5, patience=60, max_epochs=30,
                                keep_members=keep)
        initialise(ens, cfg)
        with torch.no_grad():  # member 1: its first layer's ReLUs dead on every input
            ens.params["feature_extractor__0__weight"][1] = 0.0
            ens.params["feature_extractor__0__bias"][1] = -1.0
        return train_ensemble(ens, ds, [(tr, va)] * 3, cfg, seeds=[0, 1, 2], progress=False, fresh=False,
                              leave_out_unfitted=keep == "fitted")

    result = train("fitted")
    done = {int(m): h["epoch"] for h in result.history for m in np.flatnonzero(h.get("not_fitted", []))}
    assert 1 in done and done[1] <= 10, done
    assert all(h["train_loss"][1] is None for h in result.history if h["epoch"] > done[1])
    everyone = train("all")
    assert not any("not_fitted" in h for h in everyone.history)
    assert result.member(1).history[-1]["train_loss"] is None  # per-member views of the history still work
    assert train_ensemble(init_ensemble(config, [0, 1, 2]), ds, [(tr, va)] * 3,  # the default: every member trains on
                          load_train_config("toggle_switch", max_epochs=1), seeds=[0, 1, 2],
                          progress=False).val_label_variance == pytest.approx([np.var(ds.returns[va])] * 3)
    assert everyone.best_val_loss[1] / np.var(ds.returns[va]) > 0.5  # with all its epochs: never fitted
    best = int(np.argmin(result.best_val_loss))
    assert best not in done and result.best_val_loss[best] == pytest.approx(everyone.best_val_loss[best], rel=1e-3)


def test_keep_members_fitted_serves_and_records_the_members_kept(tmp_path, monkeypatch, capsys):
    """Whatever the rule leaves out: the checkpoint holds the kept members' weights, records the
    candidates and `kept`, the serving member is the same model, and `nmrm train` says who was left out."""
    from nmrm_ros.cli.model import _print_run
    from nmrm_ros.mil import Run, load_train_config
    from nmrm_ros.mil import pipeline

    ds = make_toy_dataset("push_switch", 200, seed=0)
    everyone = fit(ds, "csc_lstm", load_train_config("push_switch", max_epochs=3, keep_members="all"), members=3,
                   progress=False)
    serving = int(everyone.model.serving_member)
    out = (serving + 1) % 3
    monkeypatch.setattr(pipeline, "fitted_members", lambda u, s: [m for m in range(len(u)) if m != out])
    cfg = load_train_config("push_switch", max_epochs=3)
    assert cfg.keep_members == "fitted"  # the default
    run = fit(ds, "csc_lstm", cfg, members=3, progress=False, out=tmp_path / "fitted")
    kept = [m for m in range(3) if m != out]
    assert run.model.members == 2 and run.kept == kept and run.chosen is None
    assert run.seeds == kept and kept[int(run.model.serving_member)] == serving
    for (name, mine), full in zip(run.model.params.items(), everyone.model.params.values()):
        torch.testing.assert_close(mine, full[kept], msg=name)
    loaded = Run.load(tmp_path / "fitted")
    assert loaded.kept == kept and loaded.meta.ensemble.candidates == 3
    assert len(loaded.meta.metrics["candidate_unexplained_variance"]) == 3
    history = loaded.meta.metrics["val_loss_history"]  # every candidate's validation loss, per epoch
    assert len(history) == run.train.epochs_run and all(len(h) == 3 for h in history)
    assert history[-1] == pytest.approx(run.train.history[-1]["val_loss"], rel=1e-5)
    _print_run(run, cfg)
    printed = capsys.readouterr().out
    assert f"left out of the served mean, as it did not fit: member {out} (" in printed
    assert "3 members in one pass" in printed and f"serving member (hidden state): {serving}" in printed
    # one member left: the single model's report says who was left out too
    monkeypatch.setattr(pipeline, "fitted_members", lambda u, s: [s])
    alone = fit(ds, "csc_lstm", cfg, members=3, progress=False)
    assert alone.model.members == 1 and alone.kept == [serving] and alone.chosen is None
    _print_run(alone, cfg)
    printed = capsys.readouterr().out
    assert "left out of the served mean, as it did not fit: member" in printed and "best epoch" in printed
    from nmrm_ros.mil.training import TrainConfig

    assert TrainConfig().keep_members == "all"  # what runs recorded before the setting trained with


def test_nmrm_train_says_how_much_of_the_returns_the_model_explains_and_warns_when_too_little(capsys):
    """The served model's validation 1 - R^2 is recorded (the validation return MSE over the variance
    of the validation labels); `nmrm train` prints the share explained, and a warning with the next
    step when it is under 1 - POORLY_FITTED (here a model of 2 epochs, which has not left the plateau)."""
    from nmrm_ros.cli.model import _print_fit, _print_run
    from nmrm_ros.mil import load_train_config
    from nmrm_ros.mil.fitted import POORLY_FITTED, poorly_fitted
    from nmrm_ros.mil.pipeline import member_splits

    ds = make_toy_dataset("push_switch", 200, seed=0)
    cfg = load_train_config("push_switch", max_epochs=2)
    run = fit(ds, "csc_lstm", cfg, members=1, progress=False)
    _, va, _ = member_splits(len(ds), 1, 0, "shared")[0][0]
    unexplained = run.meta.metrics["val_unexplained_variance"]
    assert unexplained == pytest.approx(run.meta.metrics["val"]["return_mse"] / np.var(ds.returns[va]), rel=1e-6)
    assert poorly_fitted(unexplained)
    _print_run(run, cfg)
    printed = capsys.readouterr().out
    assert f"warning: the model explains {max(0.0, 1 - unexplained):.1%} of the variance of the validation returns" in printed
    assert "Markovian plateau" in printed and "another --seed" in printed
    _print_fit(POORLY_FITTED / 10)
    assert capsys.readouterr().out == f"the model explains {1 - POORLY_FITTED / 10:.1%} of the variance of the validation returns\n"
    _print_fit(None)  # comparisons only: nothing to judge by
    assert capsys.readouterr().out == ""
    assert not poorly_fitted(None) and not poorly_fitted(float("nan"))


def test_redraws_train_new_members_when_none_fitted_and_keep_the_better_draw(tmp_path, monkeypatch, capsys):
    """cfg.redraws: a draw whose members all stopped poorly fitted (here: progress needs a halved
    loss, patience 2) is followed by K new members (seeds + REDRAW_SEED_STEP); the draw with the best
    member is kept and saved with its seeds, and every draw is recorded and printed. A draw with a
    fitted member, or one ended by the epoch limit, is the only one."""
    from nmrm_ros.cli.model import _print_run
    from nmrm_ros.mil import Run, load_train_config
    from nmrm_ros.mil import pipeline

    ds = make_toy_dataset("push_switch", 200, seed=0)
    cfg = load_train_config("push_switch", max_epochs=20, patience=2, min_improvement=0.5, redraws=1, seed=3)
    run = fit(ds, "csc_lstm", cfg, members=2, progress=False, out=tmp_path / "redrawn")
    draws = run.meta.metrics["draws"]
    step = pipeline.REDRAW_SEED_STEP
    assert [d["seeds"] for d in draws] == [[3, 4], [3 + step, 4 + step]]
    # the second draw with cfg.redraw_patience (2) times the patience and the plateau patience
    assert [list(d["patience"]) for d in draws] == [[2, cfg.plateau_patience], [4, 2 * cfg.plateau_patience]]
    assert all(d["epochs_run"] < 20 and len(d["unexplained"]) == 2 and min(d["unexplained"]) > 0.25 for d in draws)
    kept = [d for d in draws if d["kept"]]
    assert len(kept) == 1 and kept[0]["unexplained"] == min((d["unexplained"] for d in draws), key=min)
    loaded = Run.load(tmp_path / "redrawn")
    assert loaded.seeds and set(loaded.seeds) <= set(kept[0]["seeds"]) and loaded.meta.metrics["draws"] == draws
    assert run.meta.metrics["seconds"] == pytest.approx(sum(d["seconds"] for d in draws))
    _print_run(run, cfg)
    printed = capsys.readouterr().out
    assert (f"draw 2 (seeds {3 + step}, {4 + step}, patience 4 (plateau {2 * cfg.plateau_patience})): "
            f"{draws[1]['epochs_run']} epochs") in printed and "(kept)" in printed
    capped = fit(ds, "csc_lstm", load_train_config("push_switch", max_epochs=2, redraws=1), members=2, progress=False)
    assert "draws" not in capped.meta.metrics and any(capped.train.still_improving)  # the epoch limit ended it
    # one draw when a member fitted, or with redraws 0
    monkeypatch.setattr(pipeline, "poorly_fitted", lambda u: False)
    assert "draws" not in fit(ds, "csc_lstm", cfg, members=2, progress=False).meta.metrics
    monkeypatch.undo()
    single = fit(ds, "csc_lstm", cfg.__class__(**{**cfg.to_dict(), "redraws": 0}), members=2, progress=False)
    assert "draws" not in single.meta.metrics and single.seeds == [3, 4]
    repeats = fit(ds, "csc_lstm", cfg, members=2, split_mode="per_member", progress=False)  # the paper's repeats
    assert "draws" not in repeats.meta.metrics and repeats.seeds == [3, 4]
    noisy = fit(ds, "csc_lstm", cfg.__class__(**{**cfg.to_dict(), "label_swap": 0.3}), members=2, progress=False)
    assert "draws" not in noisy.meta.metrics  # labels swapped on purpose: 1 - R^2 cannot tell a plateau
    with pytest.raises(ValueError, match="redraws must be >= 0"):
        load_train_config("push_switch", redraws=-1)
    with pytest.raises(ValueError, match="redraw_patience must be >= 1"):
        load_train_config("push_switch", redraw_patience=0.5)
