"""Evaluation: BEAT2-style metrics (``metrics``), the FGD feature encoder (``fgd_encoder``), BEAT2-layout
readers (``corpus``), strict-JSON report writing (``report``) and the ``python -m livegesture.eval`` report
(``__main__``)."""
