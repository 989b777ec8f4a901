"""libtorch's oneDNN LSTM backward does not survive signals: a minimal reproduction.

Trains a small LSTM (torch.lstm, batch_first, a given initial state: the call rdpg's critic
makes, at the cue task's sizes) in a loop for SECONDS while a profiling timer sends SIGPROF to
the process every PERIOD seconds of CPU time (the kernel rounds it to its tick: ~250 signals/s
here), and prints one line if the process survives. On the 2-vCPU
AMD EPYC (Zen 4, AVX-512) VM with torch 2.11.0 the `train` mode dies within seconds
("corrupted size vs. prev_size while consolidating", or a segfault); see docs/notes/results-log.md for the
measured table. The cause is oneDNN's bug #4845 (its generated f32 GEMM kernels point rsp at
a heap workspace, so a signal frame lands on the heap), fixed in oneDNN 3.11.2; torch 2.11.0
ships oneDNN 3.10.2. Modes:

  train     forward + backward, a signal handler on the computing thread (crashes)
  train-fwd train, the signal unblocked only while the forward with a graph runs
  train-bwd train, the signal unblocked only while the backward runs (crashes)
  fwd       no-grad forwards only (the acting / evaluation path)
  mask      train, with the signals blocked in the computing thread and taken by another
            thread (what `rdpg train` does since: crates/rdpg-cli/src/stop.rs)
  nomkldnn  train, with torch.backends.mkldnn disabled (ATen's own LSTM)
  none      train, no timer (the control)

Run: .venv/bin/python scripts/repro/onednn_lstm_signals.py MODE [SECONDS] [PERIOD]
(ONEDNN_MAX_CPU_ISA=AVX2 in the environment caps oneDNN's kernels at AVX2.)
"""

import signal
import sys
import threading
import time

import torch

mode = sys.argv[1]
seconds = float(sys.argv[2]) if len(sys.argv) > 2 else 20.0
period = float(sys.argv[3]) if len(sys.argv) > 3 else 1e-4
torch.set_num_threads(1)
torch.backends.mkldnn.enabled = mode != "nomkldnn"
H, IN, B, T = 32, 32, 32, 16
handled = [0]
signal.signal(signal.SIGPROF, lambda *_: handled.__setitem__(0, handled[0] + 1))
if mode == "mask":
    # A thread started before the mask keeps the signal unblocked: the kernel picks it.
    threading.Thread(target=time.sleep, args=(seconds + 5,), daemon=True).start()
    signal.pthread_sigmask(signal.SIG_BLOCK, [signal.SIGPROF])
if mode != "none":
    signal.setitimer(signal.ITIMER_PROF, period, period)
SIG = [signal.SIGPROF]


def only_in(phase):
    """In train-fwd/train-bwd: the signal may land in `phase` only (pending ones land later)."""
    if mode in ("train-fwd", "train-bwd"):
        want = mode == "train-" + phase
        signal.pthread_sigmask(signal.SIG_UNBLOCK if want else signal.SIG_BLOCK, SIG)


torch.manual_seed(0)
w = [torch.randn(4 * H, IN), torch.randn(4 * H, H), torch.randn(4 * H), torch.randn(4 * H)]
w = [(0.1 * t).requires_grad_() for t in w]
it, t0 = 0, time.time()
while time.time() - t0 < seconds:
    with torch.no_grad():  # a burn-in scan: varying batch, no graph
        b = int(torch.randint(1, B + 1, ()).item())
        h0 = torch.zeros(1, b, H)
        torch.lstm(torch.randn(b, 4, IN), (h0, h0), w, True, 1, 0.0, True, False, True)
    if mode != "fwd":  # a critic window: forward with a graph, then backward
        x = torch.randn(B, T, IN, requires_grad=True)
        hc = (torch.randn(1, B, H), torch.randn(1, B, H))
        only_in("fwd")
        out, h, _ = torch.lstm(x, hc, w, True, 1, 0.0, True, False, True)
        loss = out.square().mean() + h.sum()
        only_in("bwd")
        loss.backward()
        only_in("neither")
        for t in w:
            t.grad = None
        if mode in ("train-fwd", "train-bwd"):
            signal.pthread_sigmask(signal.SIG_UNBLOCK, SIG)  # pending signals land here
    it += 1
signal.setitimer(signal.ITIMER_PROF, 0, 0)
print(f"survived: {mode}, {it} iterations in {time.time() - t0:.0f} s, {handled[0]} signals handled")
