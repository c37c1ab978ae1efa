"""Controller kinds: one module each (exporting ``KIND``), listed in ``registry.KINDS``."""
