"""KyberCore across processes on NATS (issue 20): which process owns which printers.

Built so far: slots (:mod:`.slots`), the broker (:mod:`.broker`) and ownership by leases in
a JetStream key-value bucket (:mod:`.leases`). The ingest and front roles that use them are
not built yet; ``kybercore serve`` is unchanged and needs none of this.
"""
