import torch

from psgrasp_training.config import config_from_dict
from psgrasp_training.model import GraspNet, kappa_clamp


def test_kappa_clamp_gradient_points_back_into_range():
    x = torch.tensor([10.0, 50.0, 200.0, 10.0, 200.0], requires_grad=True)
    y = kappa_clamp(x, 25.0, 100.0)
    assert y.tolist() == [25.0, 50.0, 100.0, 25.0, 100.0]
    # Upstream gradients: entries 0 and 2 ask to move inwards, 3 and 4 outwards.
    y.backward(torch.tensor([-1.0, 2.0, 1.0, 1.0, -1.0]))
    assert x.grad.tolist() == [-1.0, 2.0, 1.0, 0.0, 0.0]


def test_mlp_outputs_and_ranges():
    cfg = config_from_dict({"model": {"levels": 2, "base_channels": 4, "mlp_hidden": [8]}, "grid": {"dims": [8, 8, 8]}})
    torch.manual_seed(0)
    net = GraspNet(cfg).eval()
    feats = torch.randn(20, cfg.feature_dim()) * 10
    out = net.mlp(feats)
    assert torch.allclose(out["baseline"].norm(dim=1), torch.ones(20), atol=1e-6)
    assert ((out["kappa"] >= 25) & (out["kappa"] <= 100)).all()
    assert ((out["width"] > 0) & (out["width"] < 0.08)).all() and out["collision_prior"].shape == (20, 18)
    logits, encs = net.unet(torch.randn(1, 3, 8, 8, 8))
    assert logits.shape == (1, 3, 8, 8, 8) and [e.shape[1:] for e in encs] == [(4, 8, 8, 8), (8, 4, 4, 4)]
    cos = GraspNet(config_from_dict({"variant": "1app-cosine", "model": {"levels": 2, "base_channels": 4},
                                     "grid": {"dims": [8, 8, 8]}})).eval()
    assert torch.equal(cos.mlp(torch.randn(5, 12))["kappa"], torch.full((5,), 25.0))


#: The operators the Rust native runtime's MLP subset takes (`shared/inference/src/native/mlp.rs`).
NATIVE_MLP_OPERATORS = {"Gemm", "MatMul", "Add", "Sub", "Mul", "Div", "Relu", "Slice", "Gather", "ReduceSum", "Sqrt",
                        "Sigmoid", "Softplus", "Reciprocal", "Exp", "Clip", "Constant"}


def test_every_variant_exports_an_mlp_the_native_runtime_takes(tmp_path):
    import onnx

    from psgrasp_training.export import _export_onnx
    from psgrasp_training.model import MLP_OUTPUTS

    for variant in ("8app", "1app-kappa", "1app-cosine"):
        cfg = config_from_dict({"variant": variant, "model": {"levels": 2, "base_channels": 4, "mlp_hidden": [8]},
                                "grid": {"dims": [8, 8, 8]}})
        net = GraspNet(cfg).eval()
        path = tmp_path / f"{variant}.onnx"
        _export_onnx(net.mlp, (torch.randn(5, cfg.feature_dim()),), path, ["features"], list(MLP_OUTPUTS),
                     {"features": {0: "n"}})
        operators = {node.op_type for node in onnx.load(str(path)).graph.node}
        assert operators <= NATIVE_MLP_OPERATORS, (variant, operators - NATIVE_MLP_OPERATORS)
