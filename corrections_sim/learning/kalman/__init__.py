"""The Kalman family: a Gaussian belief N(θ̂, P) moved by each correction through a filter.

* :mod:`.filter`: the unscented and extended filters (eqs. K1–K7) and their predicted
  covariances; :mod:`.iterated`: re-linearized and batch updates; :mod:`.learnt_noise`: N
  learnt alongside θ (variational Bayes); :mod:`.attenuation`: corrections that deliver an
  unknown fraction of the intended change; :mod:`.selection`: where to learn next (eq. A1).
* The learners: :mod:`.learners` (KF, KF-C, KF-CL, KF-CI), :mod:`.active` (AL, AL-C,
  AL-CL), :mod:`.attenuated` (KF-A). The EKF of the paper's exposition left the registry
  (issue 66); its update, ``filter.ekf_update``, stays for plug-ins and the linear checks.
"""
