#!/usr/bin/env python3
"""Training throughput of dynforge's transformer re-built in PyTorch (CPU), the reference for bench/training.sh.

Same model, loss, optimizer and clipping as the burn trainer; random data (seeded) so that only the training step is
timed. Prints ONE JSON line on stdout:
  {"framework": "torch", "preset": "fast", "windows_per_second": ..., "steps": N, "seconds": ...}
and the parameter count / torch version on stderr.

Usage: python bench/torch_train.py --preset paper|fast --inputs F --steps N --batch B [--seq-len 64]

Attention kernel: in train mode with grad enabled, nn.TransformerEncoderLayer does not take its fused "fast path"
(that is inference-only); both self- and cross-attention go through F.multi_head_attention_forward, which (with
need_weights=False) calls F.scaled_dot_product_attention. On CPU, SDPA's flash kernel
(_scaled_dot_product_flash_attention_for_cpu) rejects dropout > 0, so with dropout 0.1 in train mode SDPA runs the
"math" backend (_scaled_dot_product_attention_math: matmul, softmax, dropout, matmul). See --profile to check.
"""

import argparse
import json
import math
import sys
import time

import torch
from torch import nn

D_MODEL = 128
D_FF = 512
LAYERS = 4
DROPOUT = 0.1
JOINTS = 6
SLOTS = 7  # per joint: the head's 7 outputs
# Output columns of [B, 6*7] kept as targets: everything but joint 0's mass/com/ixx/iyy slots (columns 2..5).
KEEP = [c for c in range(JOINTS * SLOTS) if c not in (2, 3, 4, 5)]
PRESETS = {"paper": {"heads": 32, "patch": 1}, "fast": {"heads": 4, "patch": 4}}


def sinusoidal(length: int, d: int) -> torch.Tensor:
    """Vaswani: pe[pos, 2i] = sin(pos / 10000^(2i/d)), pe[pos, 2i+1] = cos(pos / 10000^(2i/d))."""
    pos = torch.arange(length, dtype=torch.float32).unsqueeze(1)
    div = torch.exp(torch.arange(0, d, 2, dtype=torch.float32) * (-math.log(10000.0) / d))
    pe = torch.zeros(length, d)
    pe[:, 0::2] = torch.sin(pos * div)
    pe[:, 1::2] = torch.cos(pos * div)
    return pe


def encoder_layer(heads: int) -> nn.TransformerEncoderLayer:
    return nn.TransformerEncoderLayer(
        D_MODEL, heads, D_FF, dropout=DROPOUT, activation="gelu", batch_first=True, norm_first=True
    )


class DynModel(nn.Module):
    def __init__(self, inputs: int, seq_len: int, heads: int, patch: int):
        super().__init__()
        assert seq_len % patch == 0, "seq-len must be a multiple of the patch size"
        self.patch = patch
        self.tokens = seq_len // patch
        self.embed = nn.Linear(patch * inputs, D_MODEL)
        self.register_buffer("pe", sinusoidal(self.tokens, D_MODEL), persistent=False)
        # enable_nested_tensor only matters for the inference fast path with padding masks; off to avoid the warning
        # it prints for norm_first layers.
        self.encoder = nn.TransformerEncoder(encoder_layer(heads), LAYERS, enable_nested_tensor=False)
        self.encoder_norm = nn.LayerNorm(D_MODEL)
        self.queries = nn.Parameter(torch.randn(1, JOINTS, D_MODEL) * 0.02)
        self.cross = nn.MultiheadAttention(D_MODEL, heads, dropout=DROPOUT, batch_first=True)
        self.joint_norm = nn.LayerNorm(D_MODEL)
        self.joint_layer = encoder_layer(heads)
        self.head = nn.Linear(D_MODEL, SLOTS)
        self.register_buffer("keep", torch.tensor(KEEP, dtype=torch.long), persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, length, f = x.shape
        # [B, L, F] -> [B, L/patch, patch*F]: consecutive time steps grouped into one token.
        x = x.reshape(b, length // self.patch, self.patch * f)
        h = self.embed(x) + self.pe
        h = self.encoder_norm(self.encoder(h))
        q = self.queries.expand(b, -1, -1)
        # need_weights=False: same SDPA path as the encoder layers (True would materialise averaged weights).
        c, _ = self.cross(q, h, h, need_weights=False)
        j = self.joint_layer(self.joint_norm(q + c))
        out = self.head(j).reshape(b, JOINTS * SLOTS)
        return out.index_select(1, self.keep)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", choices=sorted(PRESETS), default="fast")
    ap.add_argument("--inputs", type=int, default=90)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--seq-len", type=int, default=64)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--profile", action="store_true", help="print the top CPU ops of one step to stderr")
    args = ap.parse_args()

    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    cfg = PRESETS[args.preset]
    model = DynModel(args.inputs, args.seq_len, cfg["heads"], cfg["patch"])
    model.train()
    params = sum(p.numel() for p in model.parameters())
    print(
        f"torch {torch.__version__}, threads {torch.get_num_threads()}, preset {args.preset} "
        f"(heads {cfg['heads']}, patch {cfg['patch']}, tokens {model.tokens}), parameters {params}",
        file=sys.stderr,
    )

    g = torch.Generator().manual_seed(1234)
    x = torch.randn(args.batch, args.seq_len, args.inputs, generator=g)
    y = torch.randn(args.batch, len(KEEP), generator=g)

    opt = torch.optim.AdamW(model.parameters(), lr=5e-4, betas=(0.9, 0.999), eps=1e-5, weight_decay=1e-2)
    loss_fn = nn.MSELoss()

    def step() -> float:
        opt.zero_grad(set_to_none=True)
        loss = loss_fn(model(x), y)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        return loss.item()  # forces completion, like reading the loss back in the burn trainer

    for _ in range(args.warmup):
        first = step()
    if args.profile:
        from torch.profiler import ProfilerActivity, profile

        with profile(activities=[ProfilerActivity.CPU]) as prof:
            step()
        print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=25), file=sys.stderr)

    step_times = []
    cpu0 = time.process_time()
    t0 = time.perf_counter()
    for _ in range(args.steps):
        ts = time.perf_counter()
        last = step()
        step_times.append(time.perf_counter() - ts)
    seconds = time.perf_counter() - t0
    cpu = time.process_time() - cpu0
    step_times.sort()
    median = step_times[len(step_times) // 2]
    # A CPU use well below the thread count means the machine was shared (e.g. a cargo build) while timing.
    print(
        f"loss after warm-up {first:.4f}, after {args.steps} timed steps {last:.4f}; step s min {step_times[0]:.3f} "
        f"median {median:.3f} max {step_times[-1]:.3f}; CPU use {cpu / seconds:.2f} of {torch.get_num_threads()} threads",
        file=sys.stderr,
    )
    print(
        json.dumps(
            {
                "framework": "torch",
                "preset": args.preset,
                "windows_per_second": args.steps * args.batch / seconds,
                "steps": args.steps,
                "seconds": seconds,
            }
        )
    )


if __name__ == "__main__":
    main()
