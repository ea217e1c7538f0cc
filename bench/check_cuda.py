"""The policy's CUDA path on a machine with a GPU: the checks the CPU suite makes of the decoder, on CUDA's kernels.

    python bench/check_cuda.py   # PYTHONPATH=src where ocpipe is not installed; needs torch, numpy and tqdm

1. float64 on CUDA: the last-token decoder path equals the whole decoder's last action token, values and weight
   gradients, within the same bound derived from float64's epsilon that tests/test_policy.py uses on the CPU.
2. The same float64 decoder on the same sequence, on the CPU and on CUDA (other kernels throughout), agrees within
   that bound.
3. float32 training steps on CUDA (config `device: cuda`, util.devices) lower the loss; ms per step beside the CPU's.
Exits non-zero on a failed check."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import torch

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from policy_stores import policy_settings  # noqa: E402
from tolerances import decoder_atols  # noqa: E402

from ocpipe.policy.model import PROPRIO_DIMS, SequencePolicy, loss_terms  # noqa: E402
from ocpipe.util.devices import pick_device  # noqa: E402


def inputs(policy, device, dtype, B=3, K=7, D=16, seed=0):
    g = torch.Generator().manual_seed(seed)
    T, C, P = policy["window"], len(policy["cameras"]), PROPRIO_DIMS[policy["proprio"]]
    shapes = [(B, T, C, K, D), (B, T, P), (B, T, 4)]
    return [torch.randn(*s, generator=g, dtype=dtype).to(device) for s in shapes]


def equivalence(device) -> bool:
    ok = True
    for layers, window in [(1, 1), (2, 5), (3, 4)]:
        policy = policy_settings(window=window, layers=layers, goal="2d", cameras=[0, 1])
        torch.manual_seed(0)
        cpu = SequencePolicy(policy, 7, 16).eval().double()
        gpu = SequencePolicy(policy, 7, 16).eval().double().to(device)
        gpu.load_state_dict(cpu.state_dict())
        seqs, fast_of = {}, {}
        for name, model in (("cpu", cpu), ("cuda", gpu)):
            seq = model.tokens(*inputs(policy, next(model.parameters()).device, torch.float64))[0]
            full, fast = model.action_states(seq)[:, -1], model.current_action_state(seq)
            atol, grad_atol = decoder_atols(layers, seq.shape, float(seq.detach().abs().max()),
                                            float(full.detach().abs().max()))
            grads = [torch.autograd.grad(o.square().sum(), list(model.decoder.parameters())) for o in (full, fast)]
            d_out = float((fast - full).detach().abs().max())
            d_grad = max(float((a - b).abs().max()) for a, b in zip(*grads))
            seqs[name], fast_of[name] = seq.detach(), model.current_action_state
            good = d_out <= atol and d_grad <= grad_atol
            ok &= good
            print(f"{name:4s} layers {layers} window {window}: last token vs whole decoder {d_out:.1e} (bound "
                  f"{atol:.1e}), gradients {d_grad:.1e} (bound {grad_atol:.1e}) {'ok' if good else 'FAILED'}")
        # the CPU's sequence through both devices' decoders, so only the decoder's kernels differ
        on_cpu = fast_of["cpu"](seqs["cpu"]).detach()
        on_cuda = fast_of["cuda"](seqs["cpu"].to(device)).detach().cpu()
        d_dev = float((on_cpu - on_cuda).abs().max())
        good = d_dev <= 2 * atol
        ok &= good
        print(f"     cpu vs cuda, one float64 decoder on one sequence: {d_dev:.1e} (bound {2 * atol:.1e}) "
              f"{'ok' if good else 'FAILED'}")
    return ok


def training_steps(device, steps=200) -> tuple[bool, float]:
    policy = policy_settings(window=5, layers=2, width=64, goal="2d", cameras=[0, 1], dropout=0.0)
    torch.manual_seed(0)
    model = SequencePolicy(policy, 7, 16).to(device)
    opt = torch.optim.AdamW(model.parameters(), lr=1e-3)
    x = inputs(policy, device, torch.float32, B=32)
    target = torch.randn(32, policy["horizon"], 8, generator=torch.Generator().manual_seed(1)).to(device)
    losses = []
    for i in range(steps):
        if i == 10:  # after warm-up (kernel selection, allocator)
            if device.type == "cuda":
                torch.cuda.synchronize()
            start = time.perf_counter()
        loss = loss_terms(model(*x).actions, target, torch.ones_like(target), False)["loss"]
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    if device.type == "cuda":
        torch.cuda.synchronize()
    ms = 1000 * (time.perf_counter() - start) / (steps - 10)
    return losses[-1] < 0.5 * losses[0], ms


if __name__ == "__main__":
    device = pick_device("cuda")  # refuses, naming the config value, where torch sees no GPU
    print(f"torch {torch.__version__}, {torch.cuda.get_device_name(device)}; auto picks {pick_device('auto')}")
    ok = equivalence(device)
    torch.set_num_threads(1)
    for dev in (device, torch.device("cpu")):
        learned, ms = training_steps(dev)
        ok &= learned
        print(f"{dev.type:4s} float32 training, batch 32, width 64: {ms:.2f} ms/step, loss halved: {learned}")
    print("all checks passed" if ok else "A CHECK FAILED")
    sys.exit(0 if ok else 1)
