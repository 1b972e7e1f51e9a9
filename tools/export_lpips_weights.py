#!/usr/bin/env python3
"""Writes the AlexNet-LPIPS v0.1 weights that `msnerf eval --lpips-weights FILE` reads.

msnerf computes LPIPS itself (src/output/metrics/lpips.rs) but ships no pretrained network. Run this once where
PyTorch is available:

    pip install lpips safetensors
    python3 tools/export_lpips_weights.py lpips_alex_v0.1.safetensors

It saves the `lpips` package's own state dict for LPIPS(net="alex", version="0.1") in safetensors format (float32):
the AlexNet convolutions `net.slice1.0.*` ... `net.slice5.10.*` (torchvision's ImageNet weights) and the learned
per-channel weights `lin0.model.1.weight` ... `lin4.model.1.weight`. Nothing is pickled, and msnerf needs no
Python at run time.
"""
import argparse
import re
import sys


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", help="output .safetensors file")
    args = parser.parse_args()
    try:
        import lpips
        from safetensors.torch import save_file
    except ImportError as e:
        print(f"needs the `lpips`, `torch` and `safetensors` packages (pip install lpips safetensors): {e}",
              file=sys.stderr)
        return 1
    net = lpips.LPIPS(net="alex", version="0.1", verbose=False)
    wanted = re.compile(r"^(net\.slice\d\.\d+\.(weight|bias)|lin\d\.model\.1\.weight)$")
    tensors = {k: v.detach().float().contiguous() for k, v in net.state_dict().items() if wanted.match(k)}
    if len(tensors) != 15:
        print(f"expected 15 tensors (5 convolutions with bias, 5 lin layers), found {sorted(tensors)}", file=sys.stderr)
        return 1
    save_file(tensors, args.out)
    print(f"wrote {args.out}: {', '.join(sorted(tensors))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
