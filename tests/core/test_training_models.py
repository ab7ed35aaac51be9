"""AM-YOLO / local detector shapes, weight sharing, and the loss + assigner on tiny boxes."""

from __future__ import annotations

import pytest
import torch

from gldt_core.training.blocks import C2PSA, SPPF, C3k2
from gldt_core.training.loss import DetectionLoss, TaskAlignedAssigner, ciou
from gldt_core.training.models import Detector, ModelSpec
from gldt_core.training.stff import STFF
from support import CONFIGS

TINY = dict(channels=(4, 8, 8, 16, 16), depth=1, num_classes=3, reg_max=8)

# Single-threaded: on shared CPUs OpenMP barriers make multi-threaded small ops much slower.
torch.set_num_threads(1)


def global_spec(**kw) -> ModelSpec:
    return ModelSpec(**{**TINY, "stff_levels": (2, 3, 4), "stff_windows": (4, 4, 2), **kw})


def local_spec(**kw) -> ModelSpec:
    return ModelSpec(
        **{**TINY, "dual_frame": False, "stff_levels": (), "stff_windows": (), "head_levels": (2, 3), **kw}
    )


def test_global_model_shapes_train_and_eval() -> None:
    torch.manual_seed(0)
    spec = global_spec()
    model = Detector(spec)
    assert spec.input_multiple == 32 and spec.strides == (4, 8, 16, 32)
    prev, cur = torch.rand(2, 3, 64, 96), torch.rand(2, 3, 64, 96)
    maps = model.train()(prev, cur)
    no = 4 * spec.reg_max + spec.num_classes
    assert [tuple(m.shape) for m in maps] == [(2, no, 64 // s, 96 // s) for s in (4, 8, 16, 32)]
    out = model.eval()(prev, cur)
    anchors = sum((64 // s) * (96 // s) for s in (4, 8, 16, 32))
    assert out.shape == (2, 4 + spec.num_classes, anchors)
    assert float(out[:, 4:].min().detach()) >= 0 and float(out[:, 4:].max().detach()) <= 1


def test_model_contains_the_yolo11_blocks_and_one_shared_backbone() -> None:
    model = Detector(global_spec())
    kinds = {type(m) for m in model.modules()}
    assert {C3k2, SPPF, C2PSA, STFF} <= kinds
    assert sorted(model.stff.keys()) == ["2", "3", "4"]
    assert all(float(m.alpha.detach()) == pytest.approx(0.1) for m in model.stff.values())
    # One backbone: both frames go through the same parameters, none are duplicated per frame.
    assert sum(1 for _ in model.backbone.modules() if isinstance(_, SPPF)) == 1


def test_stff_model_uses_the_previous_frame_and_ablation_does_not() -> None:
    torch.manual_seed(0)
    cur, prev_a, prev_b = torch.rand(1, 3, 64, 64), torch.rand(1, 3, 64, 64), torch.rand(1, 3, 64, 64)
    with torch.no_grad():
        amyolo = Detector(global_spec()).eval()
        assert not torch.allclose(amyolo(prev_a, cur), amyolo(prev_b, cur))
        plain = Detector(global_spec(stff_levels=(), stff_windows=())).eval()
        assert torch.equal(plain(prev_a, cur), plain(prev_b, cur))


def test_local_model_has_p2_head_and_batches() -> None:
    model = Detector(local_spec()).eval()
    x = torch.rand(4, 3, 64, 64)
    with torch.no_grad():
        out = model(x)
        single = model(x[2:3])
    assert out.shape == (4, 7, 16 * 16 + 8 * 8)
    assert torch.allclose(out[2:3], single, atol=1e-5)


def test_bad_inputs_and_specs_are_rejected() -> None:
    model = Detector(global_spec()).eval()
    with pytest.raises(ValueError, match="divisible by 32"):
        model(torch.rand(1, 3, 48, 64), torch.rand(1, 3, 48, 64))
    with pytest.raises(ValueError, match="previous, current"):
        model(torch.rand(1, 3, 64, 64))
    with pytest.raises(ValueError, match="one window size"):
        ModelSpec(stff_levels=(2, 3), stff_windows=(8,))
    with pytest.raises(ValueError, match="unknown model fields"):
        ModelSpec.from_dict({"chanels": [1, 2, 3, 4, 5]})
    assert ModelSpec(stff_levels=(2, 3, 4), stff_windows=(8, 8, 4)).input_multiple == 64


def test_assigner_gives_every_tiny_box_a_positive() -> None:
    """A 3x3 px box that contains no anchor centre still gets its nearest anchor as a positive."""
    assigner = TaskAlignedAssigner(top_k=10)
    anchors = torch.stack(
        torch.meshgrid(torch.arange(8.0) * 4 + 2, torch.arange(8.0) * 4 + 2, indexing="xy"), -1
    ).reshape(-1, 2)
    a = len(anchors)
    scores = torch.full((1, a, 2), 0.01)
    pred = torch.cat((anchors - 2, anchors + 2), 1).unsqueeze(0)
    gt = torch.tensor([[[10.2, 10.2, 13.0, 13.0], [16.5, 4.5, 27.5, 15.5]]])
    boxes, target_scores, fg, gt_idx = assigner(
        scores, pred, anchors, torch.tensor([[0, 1]]), gt, torch.tensor([[True, True]])
    )
    assert fg.sum() >= 2
    assert (gt_idx[0][fg[0]] == 0).any() and (gt_idx[0][fg[0]] == 1).any()
    nearest = ((anchors - torch.tensor([11.6, 11.6])) ** 2).sum(1).argmin()
    assert fg[0, nearest] and gt_idx[0, nearest] == 0
    assert target_scores[0, fg[0]].sum(-1).min() > 0
    assert float(target_scores[0, ~fg[0]].abs().max()) == 0.0


def test_ciou_is_one_for_identical_boxes_and_penalises_offsets() -> None:
    a = torch.tensor([[0.0, 0.0, 10.0, 10.0]])
    assert float(ciou(a, a)) == pytest.approx(1.0, abs=1e-5)
    far = torch.tensor([[20.0, 20.0, 30.0, 30.0]])
    assert float(ciou(a, far)) < 0  # no overlap: centre distance penalty makes it negative


def test_loss_decreases_when_fitting_a_small_target() -> None:
    torch.manual_seed(0)
    spec = local_spec()
    model = Detector(spec).train()
    criterion = DetectionLoss(spec.num_classes, spec.reg_max, spec.strides)
    images = torch.rand(2, 3, 64, 64) * 0.2 + 0.5
    images[0, :, 20:30, 30:42] = 0.05  # a dark "drone"
    targets = [torch.tensor([[0.0, 30.0, 20.0, 42.0, 30.0]]), torch.zeros(0, 5)]
    optimizer = torch.optim.Adam(model.parameters(), 5e-3)
    losses = []
    for _ in range(40):
        loss, parts = criterion(model(images), targets)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(float(loss.detach()))
        assert set(parts) == {"box", "cls", "dfl"}
    assert min(losses[-5:]) < 0.5 * losses[0]


def test_training_configs_load_and_reject_bad_sizes(tmp_path) -> None:

    import yaml

    from gldt_core.training.train import load_config, spec_for_task

    configs = CONFIGS / "train"
    for name, task in (("global_tiny", "global"), ("global_nostff_tiny", "global"), ("local_tiny", "local")):
        config = load_config(configs / f"{name}.yaml")
        spec = spec_for_task(task, config)
        assert spec.dual_frame == (task == "global")
    assert spec_for_task("global", load_config(configs / "global_tiny.yaml")).stff_levels == (2, 3, 4)
    raw = yaml.safe_load((configs / "global_tiny.yaml").read_text())
    raw["data"]["input_size"] = [160, 160]
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(raw))
    with pytest.raises(ValueError, match="divisible by 64"):
        load_config(bad)
    raw["data"]["input_size"] = [192, 192]
    raw["train"]["epochz"] = 3
    bad.write_text(yaml.safe_dump(raw))
    with pytest.raises(ValueError, match="unknown config key 'train.epochz'"):
        load_config(bad)


def test_a_training_config_extends_another_and_states_only_what_it_changes(tmp_path) -> None:

    from gldt_core.training.train import load_config

    configs = CONFIGS / "train"
    base, balanced = load_config(configs / "global_tiny.yaml"), load_config(configs / "global_tiny_balanced.yaml")
    assert balanced["data"]["synthetic_share"] == 0.5 and base["data"]["synthetic_share"] is None
    balanced["data"]["synthetic_share"], balanced["out_dir"] = None, base["out_dir"]
    assert balanced == base  # nothing else differs: nested keys were merged, not replaced

    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "variant.yaml").write_text("extends: ../base.yaml\ntrain:\n  epochs: 3\n")
    (tmp_path / "base.yaml").write_text("extends: sub/variant.yaml\n")
    with pytest.raises(ValueError, match="'extends' makes a cycle"):
        load_config(tmp_path / "sub" / "variant.yaml")
    (tmp_path / "base.yaml").write_text("train:\n  epochs: 7\n  lr: 0.01\n")
    config = load_config(tmp_path / "sub" / "variant.yaml")  # the path is relative to the extending file
    assert (config["train"]["epochs"], config["train"]["lr"]) == (3, 0.01)
    (tmp_path / "lost.yaml").write_text("extends: nowhere.yaml\n")
    with pytest.raises(FileNotFoundError, match=r"nowhere\.yaml \(extended by .*lost\.yaml\)"):
        load_config(tmp_path / "lost.yaml")
    (tmp_path / "odd.yaml").write_text("extends: [a.yaml]\n")
    with pytest.raises(ValueError, match="'extends' must be a path"):
        load_config(tmp_path / "odd.yaml")
    (tmp_path / "typo.yaml").write_text("extends: base.yaml\ntrain:\n  epochz: 3\n")
    with pytest.raises(ValueError, match="unknown config key 'train.epochz'"):
        load_config(tmp_path / "typo.yaml")


def test_every_shipped_training_config_loads() -> None:

    from gldt_core.training import second_stage
    from gldt_core.training.train import load_config, spec_for_task

    configs = CONFIGS / "train"
    names = sorted(configs.glob("*.yaml"))
    assert len(names) >= 10
    for path in names:
        if path.name.startswith("second_stage"):
            config = second_stage.load_config(path)
            for member in config.get(second_stage.ENSEMBLE_MEMBERS, [config]):  # an ensemble: each member
                second_stage.check_member(member)  # its model, its options and any teacher it learns from
            continue
        spec_for_task("local" if path.name.startswith("local") else "global", load_config(path))
