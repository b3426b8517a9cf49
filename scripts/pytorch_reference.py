#!/usr/bin/env python3
"""PyTorch figures to compare with `bench conv` and `bench train-step`.

Same layers, models, batch, loss and optimizer as the Rust benchmarks:
  conv        forward, input-gradient and weight-gradient GFLOP/s of the
              64->64 3x3 (padding 1) convolution on 8x64x112x112
  train-step  images/s of forward + cross-entropy + backward + Adam(1e-4)
              for AlexNet, VGG16 at width 1/4 and VGG16 (one input channel,
              two classes, batch 8 of 1x224x224); median of 5 steps after 2

usage: python3 scripts/pytorch_reference.py [conv] [train-step]
Needs torch and torchvision (pip install torch torchvision); prints one JSON
object per line. Uses every core the machine has, as the Rust side does.
"""
import json
import os
import statistics
import sys
import time

import torch
import torch.nn as nn
import torch.nn.functional as F
import torchvision

torch.set_num_threads(os.cpu_count() or 1)
torch.manual_seed(0)


def median_seconds(fn, reps=5):
    fn()
    times = []
    for _ in range(reps):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def conv_kernels():
    x = torch.rand(8, 64, 112, 112)
    w = torch.rand(64, 64, 3, 3)
    g = torch.rand(8, 64, 112, 112)
    gflop = 2 * 8 * 64 * 64 * 9 * 112 * 112 / 1e9
    with torch.no_grad():
        fwd = median_seconds(lambda: F.conv2d(x, w, padding=1))
        dx = median_seconds(lambda: torch.nn.grad.conv2d_input(x.shape, w, g, padding=1))
        dw = median_seconds(lambda: torch.nn.grad.conv2d_weight(x, w.shape, g, padding=1))
    print(json.dumps({
        "layer": "64->64 3x3 p1 on 8x64x112x112",
        "forward_gflops": round(gflop / fwd, 1),
        "input_grad_gflops": round(gflop / dx, 1),
        "weight_grad_gflops": round(gflop / dw, 1),
        "torch": torch.__version__,
    }), flush=True)


def vgg16(width_divisor):
    layers, cin = [], 1
    for c in [64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512, "M"]:
        if c == "M":
            layers.append(nn.MaxPool2d(2, 2))
        else:
            layers += [nn.Conv2d(cin, c // width_divisor, 3, padding=1), nn.ReLU(inplace=True)]
            cin = c // width_divisor
    hidden = 4096 // width_divisor
    return nn.Sequential(
        nn.Sequential(*layers), nn.AdaptiveAvgPool2d((7, 7)), nn.Flatten(1),
        nn.Linear(cin * 49, hidden), nn.ReLU(True), nn.Dropout(0.5),
        nn.Linear(hidden, hidden), nn.ReLU(True), nn.Dropout(0.5),
        nn.Linear(hidden, 2),
    )


def alexnet():
    model = torchvision.models.alexnet(weights=None, num_classes=2)
    model.features[0] = nn.Conv2d(1, 64, kernel_size=11, stride=4, padding=2)
    return model


def train_step(name, model, batch=8):
    model.train()
    optim = torch.optim.Adam(model.parameters(), lr=1e-4)
    loss_fn = nn.CrossEntropyLoss()
    x = torch.rand(batch, 1, 224, 224)
    y = torch.arange(batch) % 2

    def step():
        optim.zero_grad(set_to_none=True)
        loss_fn(model(x), y).backward()
        optim.step()

    step()
    seconds = median_seconds(step)
    print(json.dumps({"model": name, "batch": batch, "images_per_s": round(batch / seconds, 2),
                      "torch": torch.__version__}), flush=True)


def main():
    parts = sys.argv[1:] or ["conv", "train-step"]
    if "conv" in parts:
        conv_kernels()
    if "train-step" in parts:
        for name, build in [("alexnet", alexnet), ("vgg16w4", lambda: vgg16(4)), ("vgg16", lambda: vgg16(1))]:
            train_step(name, build())


if __name__ == "__main__":
    main()
