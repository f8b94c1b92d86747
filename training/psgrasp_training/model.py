"""The two-stage network: a 3D residual U-Net (label grid + encoder feature grids) and the MLP head.

Graph contract (network.md v1):
* U-Net input ``normal_grid`` [1, 3, X, Y, Z]; outputs ``label_logits`` [1, 3, X, Y, Z] (classes
  empty, contact, gripper) and ``enc0..enc{L-1}`` [1, C_l, X/2^l, Y/2^l, Z/2^l], C_l = base·2^l.
* MLP input ``features`` [N, F], F = Σ C_l; outputs ``baseline`` [N, 3] (unit), ``kappa`` [N],
  ``width`` [N] (m), ``quality_prior`` [N], ``collision_prior`` [N, 18], all activations in-graph.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

from .config import Config

#: Approach directions per contact point (paper: n_r = 18).
N_APPROACHES = 18
#: Classes of the label grid, in channel order.
CLASSES = ("empty", "contact", "gripper")
#: Raw outputs of the MLP's last layer: baseline 3, κ′ 1, width 1, quality 1, collision 18.
MLP_RAW_OUTPUTS = 3 + 1 + 1 + 1 + N_APPROACHES
#: ε of the baseline normalisation.
BASELINE_EPS = 1e-8


#: Run CPU training convolutions as a batch of two halves (see :class:`Conv3d`); False = plain PyTorch.
CPU_BATCH_SPLIT = True


def _cpu_split(x: torch.Tensor) -> bool:
    """Whether to run a convolution as a batch of two halves (see :class:`Conv3d`)."""
    return CPU_BATCH_SPLIT and x.device.type == "cpu" and torch.is_grad_enabled() and x.shape[0] == 1 and x.shape[2] % 2 == 0


class Conv3d(nn.Conv3d):
    """Conv3d that, on CPU with gradients and batch size 1, runs as a batch of two halves along X.

    PyTorch's CPU backend picks its slow im2col convolution (forward and backward) for batch size
    1 on small grids; with batch size 2 it uses oneDNN, 3–6× faster for our levels. The two halves
    carry the halo the kernel needs, so the result is the same convolution (up to summation order).
    Inference and export (no gradients) use the plain convolution.
    """

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        k, s, p = self.kernel_size[0], self.stride[0], self.padding[0]
        d_out = (x.shape[2] + 2 * p - k) // s + 1
        if not _cpu_split(x) or d_out % 2 or self.padding_mode != "zeros" or isinstance(self.padding, str):
            return super().forward(x)
        xp = F.pad(x, (0, 0, 0, 0, p, p)) if p else x
        half = d_out // 2
        length = (half - 1) * s + k
        parts = torch.cat([xp[:, :, :length], xp[:, :, half * s: half * s + length]], dim=0)
        y = F.conv3d(parts, self.weight, self.bias, self.stride, (0, *self.padding[1:]), self.dilation, self.groups)
        return torch.cat([y[0:1], y[1:2]], dim=2)


class ConvTranspose3d(nn.ConvTranspose3d):
    """ConvTranspose3d (kernel = stride, no padding) with the batch-of-two-halves CPU path of :class:`Conv3d`."""

    def forward(self, x: torch.Tensor, output_size=None) -> torch.Tensor:
        plain = (self.kernel_size != self.stride or any(self.padding) or any(self.output_padding)
                 or output_size is not None)
        if plain or not _cpu_split(x):
            return super().forward(x, output_size)
        half = x.shape[2] // 2
        parts = torch.cat([x[:, :, :half], x[:, :, half:]], dim=0)
        y = F.conv_transpose3d(parts, self.weight, self.bias, self.stride, 0, 0, self.groups, self.dilation)
        return torch.cat([y[0:1], y[1:2]], dim=2)


def _norm(channels: int, kind: str) -> nn.Module:
    return nn.BatchNorm3d(channels) if kind == "batch" else nn.Identity()


class ConvNormAct(nn.Sequential):
    """Conv3d → norm → ReLU."""

    def __init__(self, cin: int, cout: int, kernel: int, stride: int, norm: str):
        super().__init__(
            Conv3d(cin, cout, kernel, stride=stride, padding=(kernel - 1) // 2 if stride == 1 else 0,
                      bias=norm == "none"),
            _norm(cout, norm),
            nn.ReLU(inplace=True),
        )


class ResBlock(nn.Module):
    """Residual block: (3³ conv, norm, ReLU, 3³ conv, norm) + (1³ conv if the width changes), ReLU."""

    def __init__(self, cin: int, cout: int, norm: str):
        super().__init__()
        bias = norm == "none"
        self.conv1 = Conv3d(cin, cout, 3, padding=1, bias=bias)
        self.norm1 = _norm(cout, norm)
        self.conv2 = Conv3d(cout, cout, 3, padding=1, bias=bias)
        self.norm2 = _norm(cout, norm)
        self.skip = (
            nn.Identity() if cin == cout else nn.Sequential(Conv3d(cin, cout, 1, bias=bias), _norm(cout, norm))
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(self.norm1(self.conv1(x)))
        y = self.norm2(self.conv2(y))
        return F.relu(y + self.skip(x))


class ResUNet3d(nn.Module):
    """3D residual U-Net returning label logits and the encoder feature grid of every level."""

    def __init__(self, levels: int = 4, base_channels: int = 8, blocks_per_level: int = 1, norm: str = "batch",
                 in_channels: int = 3, classes: int = 3):
        super().__init__()
        self.levels = levels
        self.channels = [base_channels * 2**level for level in range(levels)]
        ch = self.channels
        self.stem = ConvNormAct(in_channels, ch[0], 3, 1, norm)
        self.down = nn.ModuleList([ConvNormAct(ch[level - 1], ch[level], 2, 2, norm) for level in range(1, levels)])
        self.enc = nn.ModuleList(
            [nn.Sequential(*[ResBlock(ch[level], ch[level], norm) for _ in range(blocks_per_level)])
             for level in range(levels)]
        )
        self.up = nn.ModuleList(
            [ConvTranspose3d(ch[level + 1], ch[level], 2, stride=2) for level in range(levels - 1)]
        )
        self.dec = nn.ModuleList(
            [nn.Sequential(ResBlock(2 * ch[level], ch[level], norm),
                           *[ResBlock(ch[level], ch[level], norm) for _ in range(blocks_per_level - 1)])
             for level in range(levels - 1)]
        )
        self.head = Conv3d(ch[0], classes, 1)

    def forward(self, normal_grid: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """normal_grid [B, 3, X, Y, Z] → (label_logits [B, 3, X, Y, Z], [enc0, …, enc{L-1}])."""
        x = self.enc[0](self.stem(normal_grid))
        encs = [x]
        for level in range(1, self.levels):
            x = self.enc[level](self.down[level - 1](x))
            encs.append(x)
        for level in range(self.levels - 2, -1, -1):
            x = self.dec[level](torch.cat([self.up[level](x), encs[level]], dim=1))
        return self.head(x), encs


class _InwardClamp(torch.autograd.Function):
    """clamp(x, lo, hi) whose gradient also flows where x is outside [lo, hi], but only when a descent
    step moves x back towards the range (a hard clamp has zero gradient there, so κ could never leave
    a bound once it reached it)."""

    @staticmethod
    def forward(ctx, x, lo: float, hi: float):
        ctx.save_for_backward(x)
        ctx.lo, ctx.hi = lo, hi
        return x.clamp(lo, hi)

    @staticmethod
    def backward(ctx, grad):
        (x,) = ctx.saved_tensors
        # Descent changes x by −grad: below lo it must increase (grad < 0), above hi decrease (grad > 0).
        keep = ((x >= ctx.lo) & (x <= ctx.hi)) | ((x < ctx.lo) & (grad < 0)) | ((x > ctx.hi) & (grad > 0))
        return grad * keep, None, None


def kappa_clamp(x: torch.Tensor, lo: float, hi: float) -> torch.Tensor:
    """κ clamp: plain ``clamp`` without gradients (inference, export), :class:`_InwardClamp` in training."""
    if torch.is_grad_enabled() and x.requires_grad:
        return _InwardClamp.apply(x, lo, hi)
    return torch.clamp(x, min=lo, max=hi)


class GraspMlp(nn.Module):
    """MLP head: features [N, F] → baseline, κ, width, quality prior, collision priors."""

    def __init__(self, feature_dim: int, hidden: list[int], kappa0: float = 25.0, kappa_eps: float = 1e-6,
                 max_opening_m: float = 0.08, kappa_learned: bool = True):
        super().__init__()
        layers: list[nn.Module] = []
        width = feature_dim
        for h in hidden:
            layers += [nn.Linear(width, h), nn.ReLU(inplace=True)]
            width = h
        self.body = nn.Sequential(*layers)
        self.out = nn.Linear(width, MLP_RAW_OUTPUTS)
        self.kappa0 = float(kappa0)
        self.kappa_eps = float(kappa_eps)
        self.max_opening_m = float(max_opening_m)
        self.kappa_learned = bool(kappa_learned)

    def forward(self, features: torch.Tensor) -> dict[str, torch.Tensor]:
        """Returns dict with ``baseline`` [N,3], ``kappa`` [N], ``width`` [N], ``quality_prior`` [N],
        ``collision_prior`` [N,18]."""
        raw = self.out(self.body(features))
        b = raw[:, 0:3]
        baseline = b / torch.clamp(torch.sqrt((b * b).sum(dim=1, keepdim=True)), min=BASELINE_EPS)
        width = self.max_opening_m * torch.sigmoid(raw[:, 4])
        if self.kappa_learned:
            kappa_inv = F.softplus(raw[:, 3])
            kappa = kappa_clamp(self.kappa0 / (kappa_inv + self.kappa_eps), self.kappa0, 4.0 * self.kappa0)
        else:
            # `width * 0 + κ0`, not `full_like`: the latter exports as Shape/ConstantOfShape,
            # which the native runtime's MLP subset does not take (width is always finite).
            kappa = width * 0.0 + self.kappa0
        return {
            "baseline": baseline,
            "kappa": kappa,
            "width": width,
            "quality_prior": torch.sigmoid(raw[:, 5]),
            "collision_prior": torch.sigmoid(raw[:, 6:]),
        }


#: MLP output names in graph order.
MLP_OUTPUTS = ("baseline", "kappa", "width", "quality_prior", "collision_prior")


class GraspNet(nn.Module):
    """U-Net + MLP, built from a :class:`Config`."""

    def __init__(self, cfg: Config):
        super().__init__()
        m = cfg.model
        self.unet = ResUNet3d(m.levels, m.base_channels, m.blocks_per_level, m.norm)
        self.mlp = GraspMlp(cfg.feature_dim(), list(m.mlp_hidden), m.kappa0, m.kappa_eps, cfg.grid.max_opening_m,
                            cfg.kappa_learned)


class UnetExport(nn.Module):
    """ONNX wrapper: one tensor per output (label_logits, enc0, …)."""

    def __init__(self, unet: ResUNet3d):
        super().__init__()
        self.unet = unet

    def forward(self, normal_grid: torch.Tensor) -> tuple[torch.Tensor, ...]:
        logits, encs = self.unet(normal_grid)
        return (logits, *encs)


class MlpExport(nn.Module):
    """ONNX wrapper: outputs in MLP_OUTPUTS order."""

    def __init__(self, mlp: GraspMlp):
        super().__init__()
        self.mlp = mlp

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, ...]:
        out = self.mlp(features)
        return tuple(out[name] for name in MLP_OUTPUTS)
