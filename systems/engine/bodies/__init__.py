"""Soft bodies behind one API (thesis ch. 5 and the models it is compared with in 6.2).

`body = Model(...)`, `body.grab(ids, targets)`, `body.step(dt)`, `body.release()`, `body.cut(...)`,
then read `body.positions` and `body.moved`. Models: ChainMail (`ChainMailBody`, thesis 5.2), XPBD
(`XPBDBody`) and projective dynamics (`ProjectiveBody`); `make_body(model, ...)` picks one by name.
"""
