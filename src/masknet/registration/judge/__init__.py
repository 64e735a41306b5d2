"""The judge: the prepared pair, every fit of a pose, the verdict (``assess_registration``) and its constraint analysis, and the arbiter, where every choice between poses is made."""
