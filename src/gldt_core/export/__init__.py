"""Export time: ONNX export of trained checkpoints (:mod:`.onnx_export`, needs torch) and the
graph surgery and quantization done on exported files (:mod:`.feature_split`,
:mod:`.window_rewrite`, :mod:`.quantize`, onnx and onnxruntime only). Nothing at run time imports
this package: the runtime detectors (:mod:`gldt_core.detect`) only load the files it writes.
"""
