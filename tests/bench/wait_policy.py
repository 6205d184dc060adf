"""CPU and wall seconds of 60 forward passes of a small conv net on two torch threads, under the OpenMP
wait-policy variables the environment sets (run it beside busy loops to see spin-waiting; not part of
make bench).

    TAG=default python tests/bench/wait_policy.py; GOMP_SPINCOUNT=0 TAG=spin0 python tests/bench/wait_policy.py
"""
import os, time, resource, sys
import torch
torch.set_num_threads(2)
m = torch.nn.Sequential(torch.nn.Conv2d(3,32,5), torch.nn.ReLU(), torch.nn.Conv2d(32,32,3))
x = torch.randn(8,3,64,64)
t0=time.perf_counter(); c0=time.process_time()
with torch.no_grad():
    for _ in range(60): m(x)
print(os.environ.get("TAG"), "wall %.2f cpu %.2f" % (time.perf_counter()-t0, time.process_time()-c0))
