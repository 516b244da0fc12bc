"""Offline training: dataset assembly, Bag-of-Words + SVM, evaluation, report, ONNX export."""
