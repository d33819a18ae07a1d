"""Evaluation: BEAT2-style metrics (``metrics``), the FGD feature encoder (``fgd_encoder``), BEAT2-layout
readers (``corpus``) and the ``python -m livegesture.eval`` report (``__main__``)."""
