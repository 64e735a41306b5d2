"""The call: what ``register`` resolved from its arguments (the plan, options, method table, validation, units), the stages of a Mask-X call, the result, and many pairs."""
