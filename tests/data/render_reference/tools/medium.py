import sys
P = {"marble": ([2.19, 2.62, 3.00], [0.0021, 0.0041, 0.0071], 1.5),
     "apple": ([2.29, 2.39, 1.97], [0.0030, 0.0034, 0.046], 1.3),
     "ketchup": ([0.18, 0.07, 0.03], [0.061, 0.97, 1.45], 1.3),
     "skin1": ([0.74, 0.88, 1.01], [0.032, 0.17, 0.48], 1.3)}
for name, (ss, sa, eta) in P.items():
    st = [a + b for a, b in zip(ss, sa)]; al = [a / t for a, t in zip(ss, st)]; pk = max(st)
    open(f"ref/{name}.xml", "w").write(f"""<scene version="3.0.0">
    <bsdf type="dielectric" id="{name}-bsdf"><float name="int_ior" value="{eta}"/><float name="ext_ior" value="1"/></bsdf>
    <medium type="homogeneous" id="{name}-medium">
        <rgb name="albedo" value="{', '.join(map(str, al))}"/>
        <rgb name="sigma_t" value="{', '.join(str(t / pk) for t in st)}"/>
        <float name="scale" value="{pk}"/><phase type="isotropic"/>
    </medium>
</scene>
""")
