# Config digests as files in the results folder, so that an edited key reruns its rule in a copy or checkout too.
rule config_digest:
    output:
        L.rule_digest(),
    log:
        L.log("config_digest", "{rule}-{digest}"),
    wildcard_constraints:
        rule=r"[a-z][a-z0-9_]*",
        digest=r"[0-9a-f]+",
    localrule: True
    message:
        "Config digest of rule {wildcards.rule}: {wildcards.digest}"
    run:
        frng_digests.write_rule_digest(config, wildcards.rule, output[0], log=log[0])
