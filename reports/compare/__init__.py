"""``viewfuse compare``: runs read from their folders (``runs``) and the comparison page (``page``)."""
