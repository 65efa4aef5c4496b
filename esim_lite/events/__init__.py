"""Events: contrast thresholds (``thresholds``), the compiled event kernel (``kernel``) and
its numpy/Python references (``reference``), sensor noise (``noise``), the event camera
(``simulator``), adaptive sampling (``sampling``), and the torch/Triton kernels for GPUs
(``torch_kernel``, ``triton_kernel``, sharing ``buffers``; the only users of torch here)."""
