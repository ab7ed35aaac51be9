"""PyTorch side of the detectors: models (AM-YOLO with STFF, local P2 detector), loss, data, training, export.

This package is the only place in gldt_core allowed to import torch (an optional extra:
``pip install torch==2.13.0 onnx``); nothing outside it imports it at module level, so the runtime
(:mod:`gldt_core.detect`, onnxruntime only) stays torch-free.

Modules: :mod:`.blocks` (YOLO11 layers), :mod:`.stff` (paper eqs. 1-8), :mod:`.models`
(:class:`~.models.Detector`, :class:`~.models.ModelSpec`), :mod:`.loss` (task-aligned assigner,
BCE + CIoU + DFL), :mod:`.data` (Halmstad + synthetic pairs, consistent augmentation),
:mod:`.train` (``gldt train``); export to ONNX lives in :mod:`gldt_core.export`.

Reproduce the shipped models (CPU, one thread each, run one after the other)::

    gldt train local  --config src/gldt_core/configs/train/local_tiny.yaml
    gldt train global --config src/gldt_core/configs/train/global_tiny.yaml
    gldt train global --config src/gldt_core/configs/train/global_nostff_tiny.yaml
    gldt export runs/local_tiny/last.pt         --out src/gldt_core/models/local_p2.onnx
    gldt export runs/global_tiny/last.pt        --out src/gldt_core/models/global_amyolo.onnx
    gldt export runs/global_nostff_tiny/last.pt --out src/gldt_core/models/global_nostff.onnx
"""
